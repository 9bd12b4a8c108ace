"""Files someone sends you are data: a crafted checkpoint, run.json, config.yaml or model file runs
no code, reads nothing outside its folder, is bounded before it is read, and is refused in one line.

Each crafted file is built here from a real run; where a payload would leave a marker file, the
test checks that the marker does not exist.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch

from data_helpers import make_data_dir
from test_run_trust import FAST, copy_run, hypa, one_line_error, recorded

ZEN = "Beautiful is better than ugly"


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    return make_data_dir(tmp_path_factory.mktemp("received") / "data", duration_s=6.0)


@pytest.fixture(scope="module")
def run(tmp_path_factory, data: Path) -> Path:
    """One finished physics-only run (read-only for the tests: they copy it)."""
    folder = tmp_path_factory.mktemp("received") / "run"
    result = hypa("hypa train", *FAST, f"data.dir={data}", f"hydra.run.dir={folder}")
    assert result.returncode == 0, result.stderr[-3000:]
    return folder


def edit_checkpoint(folder: Path, change) -> Path:
    """Change the recorded best checkpoint's stored settings with ``change(hparams)`` and re-record
    its checksum, as a sender who crafts a run would."""
    from hypa.core.metadata import sha256

    checkpoint = folder / recorded(folder)["path"]
    state = torch.load(checkpoint, weights_only=True)
    change(state["hyper_parameters"])
    torch.save(state, checkpoint)
    record = json.loads((folder / "run.json").read_text())
    record["best_checkpoint"]["sha256"] = sha256(checkpoint)
    (folder / "run.json").write_text(json.dumps(record))
    return checkpoint


def with_network(hparams: dict, **network) -> None:
    """Add a network block to the stored model (so that its network would be built) and set ``network``."""
    hparams["model_config"]["blocks"]["net"] = {"kind": "ann", "inputs": ["steering_wheel_angle"],
                                                "outputs": ["unused_correction"], "scale_as": ["yaw_rate"]}
    hparams.update(network)


@pytest.mark.parametrize("command, argument", [
    pytest.param("hypa evaluate", "run={folder}", id="evaluate"),
    pytest.param("hypa export", "run={folder}", id="export"),
    pytest.param("hypa explain", "run={folder}", id="explain"),
    pytest.param("hypa train", "ckpt_path='{checkpoint}'", id="train-resume"),
])
def test_a_target_node_among_the_network_settings_is_never_built(command: str, argument: str, run: Path,
                                                                  data: Path, tmp_path: Path) -> None:
    folder = copy_run(run, tmp_path / "run")
    marker = tmp_path / "payload-ran"
    node = {"_target_": "builtins.open", "file": str(marker), "mode": "w"}
    checkpoint = edit_checkpoint(folder, lambda h: with_network(h, ann_hparams={"hidden_size": node}))
    extra = [*FAST, f"data.dir={data}"] if command == "hypa train" else []
    arguments = argument.format(folder=folder, checkpoint=checkpoint)
    result = hypa(command, arguments, *extra, f"hydra.run.dir={tmp_path / 'out'}")
    one_line_error(result, command, "hyperparameter hidden_size must be", "dict")
    assert not marker.exists()


def test_build_ann_calls_the_class_and_never_instantiates_a_value(tmp_path: Path) -> None:
    from hypa.ann import build_ann

    marker = tmp_path / "payload-ran"
    with pytest.raises(TypeError, match="hidden_size must be a number"):
        build_ann("lstm", 1, 1, hidden_size={"_target_": "builtins.open", "file": str(marker), "mode": "w"})
    with pytest.raises(TypeError, match="unknown hyperparameter"):
        build_ann("lstm", 1, 1, _target_="builtins.print")
    assert not marker.exists()
    built = build_ann("lstm", 2, 3, hidden_size=4)  # plain values still build
    assert built.hidden_size == 4


@pytest.mark.parametrize("change, imports", [
    pytest.param(lambda h: with_network(h, ann_name="os.system"), "os.system", id="network-os.system"),
    pytest.param(lambda h: with_network(h, ann_name="this"), "this", id="network-this"),
    pytest.param(lambda h: h["model_config"]["blocks"]["single_track"].update(system="this:Zen"), "this:Zen",
                 id="system-this"),
])
def test_a_checkpoint_imports_no_module_it_names(change, imports: str, run: Path, tmp_path: Path) -> None:
    folder = copy_run(run, tmp_path / "run")
    edit_checkpoint(folder, change)
    result = hypa("hypa evaluate", f"run={folder}", f"hydra.run.dir={tmp_path / 'out'}")
    one_line_error(result, "hypa evaluate", "not built into hypa", f"trust=[{imports}]")
    assert ZEN not in result.stdout + result.stderr  # the module `this` prints it when imported


def test_trust_names_the_code_a_run_may_import(run: Path, tmp_path: Path) -> None:
    """Trusted, the import goes ahead (and here fails in one line: `this` has no network)."""
    folder = copy_run(run, tmp_path / "run")
    edit_checkpoint(folder, lambda h: with_network(h, ann_name="this.Nothing"))
    result = hypa("hypa evaluate", f"run={folder}", "trust=[this]", f"hydra.run.dir={tmp_path / 'out'}")
    one_line_error(result, "hypa evaluate", "this.Nothing")
    assert "not built into hypa" not in result.stderr
    result = hypa("hypa evaluate", f"run={folder}", "trust=['os.system rm']", f"hydra.run.dir={tmp_path / 'out'}")
    one_line_error(result, "hypa evaluate", "is not an import path")


SETTINGS = {
    "target-key": (lambda h: with_network(h, ann_hparams={"_target_": "builtins.print"}), "unknown hyperparameter"),
    "dict-for-number": (lambda h: h.update(dt={"seconds": 1}), "its setting dt"),
    "horizon-out-of-range": (lambda h: h.update(horizon=10**12), "its setting horizon"),
    "huge-horizon": (lambda h: h.update(horizon=5_000_000), "asks for lifted matrices of at least"),
    "string-for-list": (lambda h: h.update(input_names="steering"), "its setting input_names"),
    "zero-scale": (lambda h: h["normalization"].update(std=[0.0] * len(h["normalization"]["std"])), "normalization"),
    "no-blocks": (lambda h: h.update(model_config={"name": "x", "blocks": {}}), "its model"),
    "huge-network": (lambda h: with_network(h, ann_hparams={"hidden_size": 100_000}), "its settings make a network of"),
}


@pytest.mark.parametrize("case", ["dict-for-number", "huge-network"])
def test_stored_settings_are_checked_before_anything_is_built(case: str, run: Path, tmp_path: Path) -> None:
    change, message = SETTINGS[case]
    folder = copy_run(run, tmp_path / "run")
    edit_checkpoint(folder, change)
    result = hypa("hypa evaluate", f"run={folder}", f"hydra.run.dir={tmp_path / 'out'}")
    one_line_error(result, "hypa evaluate", message)


@pytest.mark.parametrize("case", sorted(SETTINGS))
def test_every_stored_setting_is_checked_by_the_loader_every_command_shares(case: str, run: Path,
                                                                          tmp_path: Path) -> None:
    """The same cases in this process, through load_run (what evaluate, export, explain, the benchmark
    and the diagnosis call): a user error, with the message, before anything is built."""
    from hypa.core.errors import UserError
    from hypa.evaluation.runs import load_run

    change, message = SETTINGS[case]
    folder = copy_run(run, tmp_path / "run")
    edit_checkpoint(folder, change)
    with pytest.raises(UserError, match=message.replace("(", r"\(")):
        load_run(folder)


def test_run_json_names_no_file_outside_its_folder(run: Path, tmp_path: Path) -> None:
    other = copy_run(run, tmp_path / "other")
    folder = copy_run(run, tmp_path / "run")
    record = json.loads((folder / "run.json").read_text())
    for path in (str(other / recorded(other)["path"]), f"../other/{recorded(other)['path']}"):
        record["best_checkpoint"]["path"] = path
        (folder / "run.json").write_text(json.dumps(record))
        result = hypa("hypa evaluate", f"run={folder}", f"hydra.run.dir={tmp_path / 'out'}")
        one_line_error(result, "hypa evaluate", "best_checkpoint.path", "not inside", "not followed")
    record["best_checkpoint"]["path"] = "checkpoints/linked.ckpt"
    (folder / "run.json").write_text(json.dumps(record))
    (folder / "checkpoints" / "linked.ckpt").symlink_to(other / recorded(other)["path"])
    result = hypa("hypa evaluate", f"run={folder}", f"hydra.run.dir={tmp_path / 'out'}")
    one_line_error(result, "hypa evaluate", "is a symbolic link")


def test_a_missing_checksum_is_a_refusal_with_the_way_to_take_the_file(run: Path, tmp_path: Path) -> None:
    folder = copy_run(run, tmp_path / "run")
    record = json.loads((folder / "run.json").read_text())
    del record["best_checkpoint"]["sha256"]
    (folder / "run.json").write_text(json.dumps(record))
    result = hypa("hypa evaluate", f"run={folder}", f"hydra.run.dir={tmp_path / 'out'}")
    checkpoint = folder / record["best_checkpoint"]["path"]
    one_line_error(result, "hypa evaluate", "records no checksum", f"run='{checkpoint}'")
    named = hypa("hypa evaluate", f"run='{checkpoint}'", f"hydra.run.dir={tmp_path / 'out2'}")
    assert named.returncode == 0, named.stderr[-2000:]


def test_a_missing_best_names_the_newest_one_there_is(run: Path, tmp_path: Path) -> None:
    folder = copy_run(run, tmp_path / "run")
    best = folder / recorded(folder)["path"]
    newer = best.with_name("best-epoch=07.ckpt")
    best.rename(newer)
    result = hypa("hypa evaluate", f"run={folder}", f"hydra.run.dir={tmp_path / 'out'}")
    one_line_error(result, "hypa evaluate", "is missing", f"run='{newer}'")


def test_the_record_names_the_new_best_before_the_old_is_removed(tmp_path: Path) -> None:
    """The checkpoint rotation saves the new best, then removes the old: a kill in between must leave
    run.json naming a file that exists."""
    from hypa.training.checkpoints import RecordedCheckpoint
    from hypa.training.run_folder import RunFolder

    folder = RunFolder(tmp_path / "run")
    folder.checkpoints.mkdir(parents=True)
    old, new = folder.checkpoints / "best-epoch=00.ckpt", folder.checkpoints / "best-epoch=01.ckpt"
    old.write_bytes(b"old")
    new.write_bytes(b"new")
    callback = RecordedCheckpoint(folder)
    callback.best_model_path, callback.best_model_score = str(new), torch.tensor(0.5)
    seen = []

    def remove(path: str) -> None:  # what a process killed right here would leave
        seen.append(json.loads((folder.path / "run.json").read_text())["best_checkpoint"]["path"])
        Path(path).unlink()

    trainer = SimpleNamespace(is_global_zero=True, current_epoch=1, strategy=SimpleNamespace(remove_checkpoint=remove))
    callback._remove_checkpoint(trainer, str(old))
    assert seen == ["checkpoints/best-epoch=01.ckpt"]
    assert not old.exists()


def test_a_zip_bomb_checkpoint_is_refused_before_it_is_unpacked(run: Path, tmp_path: Path) -> None:
    folder = copy_run(run, tmp_path / "run")
    checkpoint = folder / recorded(folder)["path"]
    source = zipfile.ZipFile(checkpoint)
    bomb = tmp_path / "bomb.ckpt"
    with zipfile.ZipFile(bomb, "w") as out:
        for member in source.infolist():
            out.writestr(member, source.read(member))
        prefix = source.infolist()[0].filename.split("/")[0]
        member = zipfile.ZipInfo(f"{prefix}/data/99")
        member.compress_type = zipfile.ZIP_DEFLATED
        with out.open(member, "w", force_zip64=True) as big:
            chunk = bytes(2**24)
            for _ in range(64):  # 1 GiB of zeros in about 1 MB
                big.write(chunk)
    assert bomb.stat().st_size < 8 * 2**20
    result = hypa("hypa evaluate", f"run={bomb}", f"hydra.run.dir={tmp_path / 'out'}")
    one_line_error(result, "hypa evaluate", "compressed", "not read")


def test_a_yaml_alias_bomb_is_refused_not_expanded(run: Path, tmp_path: Path) -> None:
    folder = copy_run(run, tmp_path / "run")
    lines = ["a: &a [x, x, x, x, x, x, x, x, x, x]"]
    lines += [f"{chr(98 + i)}: &{chr(98 + i)} [{', '.join(['*' + chr(97 + i)] * 10)}]" for i in range(9)]
    original = (folder / "config.yaml").read_text()
    (folder / "config.yaml").write_text(original + "\n".join(lines) + "\n")
    result = hypa("hypa evaluate", f"run={folder}", f"hydra.run.dir={tmp_path / 'out'}")
    one_line_error(result, "hypa evaluate", "config.yaml")
    (folder / "config.yaml").write_text(original + "x: !!python/object/apply:os.system ['touch payload']\n")
    result = hypa("hypa evaluate", f"run={folder}", f"hydra.run.dir={tmp_path / 'out'}", cwd=tmp_path)
    one_line_error(result, "hypa evaluate", "config.yaml", "not a readable run configuration")
    assert not (tmp_path / "payload").exists()


def test_a_received_model_file_is_data(run: Path, data: Path, tmp_path: Path) -> None:
    """hypa diagnose's next step trains its written model by model_file=: a crafted one (re-headed
    ``# @package _global_`` with a callback, an import path, an interpolation) runs nothing."""
    written = copy_run(run, tmp_path / "run") / "config.yaml"
    import yaml

    model = yaml.safe_load(written.read_text())["model"]
    marker = tmp_path / "payload-ran"
    crafted = tmp_path / "diagnosed.yaml"
    global_ = {"callbacks": {"x": {"_target_": "builtins.open", "file": str(marker), "mode": "w"}}, **model}
    crafted.write_text("# @package _global_\n" + yaml.safe_dump(global_))
    result = hypa("hypa train", *FAST, f"data.dir={data}", f"model_file={crafted}", f"hydra.run.dir={tmp_path / 'a'}")
    one_line_error(result, "hypa train", "unknown keys ['callbacks']")
    assert not marker.exists()
    model["blocks"]["single_track"]["system"] = "this:Zen"
    crafted.write_text(yaml.safe_dump(model))
    result = hypa("hypa train", *FAST, f"data.dir={data}", f"model_file={crafted}", f"hydra.run.dir={tmp_path / 'b'}")
    one_line_error(result, "hypa train", "not built into hypa", "trust=[this:Zen]")
    assert ZEN not in result.stdout + result.stderr
    model["blocks"]["single_track"]["system"] = "${oc.env:HOME}"
    crafted.write_text(yaml.safe_dump(model))
    result = hypa("hypa train", *FAST, f"data.dir={data}", f"model_file={crafted}", f"hydra.run.dir={tmp_path / 'c'}")
    one_line_error(result, "hypa train", "interpolation")


def test_a_model_file_trains_as_the_model_it_holds(run: Path, data: Path, tmp_path: Path) -> None:
    import yaml

    model = yaml.safe_load((run / "config.yaml").read_text())["model"]
    model["name"] = "received"
    file = tmp_path / "received.yaml"
    file.write_text(yaml.safe_dump(model))
    out = tmp_path / "trained"
    result = hypa("hypa train", *FAST, f"data.dir={data}", f"model_file={file}", f"hydra.run.dir={out}")
    assert result.returncode == 0, result.stderr[-3000:]
    assert yaml.safe_load((out / "config.yaml").read_text())["model"]["name"] == "received"
    evaluated = hypa("hypa evaluate", f"run={out}", f"hydra.run.dir={tmp_path / 'eval'}")
    assert evaluated.returncode == 0, evaluated.stderr[-3000:]


def test_a_resumed_checkpoint_makes_the_rotation_remove_nothing_outside_its_folder(run: Path, data: Path,
                                                                                   tmp_path: Path) -> None:
    """The checkpoint callback's stored state names the files the rotation removes when a better epoch
    comes: crafted to name files outside the run, they are dropped, and the files stay."""
    from hypa.core.metadata import sha256

    folder = copy_run(run, tmp_path / "run")
    victims = [tmp_path / "victim.txt", tmp_path / "victim2.txt"]
    for victim in victims:
        victim.write_text("keep me")
    checkpoint = folder / recorded(folder)["path"]
    state = torch.load(checkpoint, weights_only=True)
    key = next(k for k in state["callbacks"] if k.startswith("RecordedCheckpoint"))
    outside = [str(folder / "checkpoints" / ".." / ".." / v.name) for v in victims]
    state["callbacks"][key].update(dirpath=str(folder / "checkpoints"), best_model_path=outside[0],
                                   kth_best_model_path=outside[0], best_k_models={outside[0]: torch.tensor(1e9)},
                                   best_model_score=torch.tensor(1e9), kth_value=torch.tensor(1e9),
                                   last_model_path=outside[1])
    torch.save(state, checkpoint)
    record = json.loads((folder / "run.json").read_text())
    record["best_checkpoint"]["sha256"] = sha256(checkpoint)
    (folder / "run.json").write_text(json.dumps(record))
    result = hypa("hypa train", *[o for o in FAST if not o.startswith("trainer.max_epochs")], "trainer.max_epochs=4",
                  f"data.dir={data}", f"ckpt_path='{checkpoint}'", f"hydra.run.dir={tmp_path / 'hydra'}")
    assert result.returncode == 0, result.stderr[-3000:]
    assert all(v.read_text() == "keep me" for v in victims)


@pytest.mark.parametrize("name", ["/tmp/received-evil", "../../evil", "a.b"])
def test_a_name_that_is_a_path_is_refused(name: str, run: Path, tmp_path: Path) -> None:
    """Channel and signal names become figure file names: one that is a path is no name."""
    from hypa.core.errors import UserError
    from hypa.evaluation.runs import load_run

    folder = copy_run(run, tmp_path / "run")
    def rename(h: dict) -> None:
        h["output_names"] = [name if n == "yaw_rate" else n for n in h["output_names"]]
    edit_checkpoint(folder, rename)
    with pytest.raises(UserError, match="is not a name"):
        load_run(folder)
    from hypa.models.spec import parse_model_spec

    with pytest.raises(UserError, match="is not a name"):
        parse_model_spec({"name": "m", "blocks": {"net": {"kind": "ann", "outputs": [name]}}})


def test_deep_yaml_and_a_linked_run_json_are_one_line(run: Path, tmp_path: Path) -> None:
    folder = copy_run(run, tmp_path / "run")
    original = (folder / "config.yaml").read_text()
    (folder / "config.yaml").write_text(original + "deep: " + "[" * 100_000 + "]" * 100_000 + "\n")
    result = hypa("hypa evaluate", f"run={folder}", f"hydra.run.dir={tmp_path / 'out'}")
    one_line_error(result, "hypa evaluate", "nested more than")
    (folder / "config.yaml").write_text(original)
    outside = tmp_path / "outside.json"
    (folder / "run.json").rename(outside)
    (folder / "run.json").symlink_to(outside)
    result = hypa("hypa evaluate", f"run={folder}", f"hydra.run.dir={tmp_path / 'out2'}")
    one_line_error(result, "hypa evaluate", "run.json is a symbolic link")
