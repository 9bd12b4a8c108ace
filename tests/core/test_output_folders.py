"""One command, one folder (hypa/core/folders.py, hypa/commands/output_folder.py): every command that writes a folder
holds it, a received folder with a link in it is written by none, Hydra's record of a run survives a
refused second writer, and default folder names do not collide.

The commands run as a user types them, several at once where they are independent (each start
imports torch: seconds).
"""

from __future__ import annotations

import os
import re
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from hypa.conf import CONF
from hypa.core.errors import UserError
from hypa.core.folders import FolderRefused, claim, take, write_atomic, write_text_atomic

from conftest import ROOT
from data_helpers import make_data_dir
from test_run_trust import FAST, copy_run, hypa, one_line_error

HELD_BY_TESTS = "hypa diagnose"


def start(command: str, *args: str) -> subprocess.Popen:
    environment = {k: v for k, v in os.environ.items() if k not in ("HYDRA_FULL_ERROR", "HYPA_FULL_ERROR")}
    return subprocess.Popen([sys.executable, "-m", *command.split(), *args], cwd=ROOT, env=environment, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def finish(process: subprocess.Popen) -> subprocess.CompletedProcess:
    out, err = process.communicate(timeout=300)
    return subprocess.CompletedProcess(process.args, process.returncode, out, err)


def outside(tmp_path: Path) -> tuple[Path, bytes, int]:
    """A file outside every folder a command writes, what it holds and when it was last written."""
    target = tmp_path / "outside" / "precious.txt"
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_bytes(b"not hypa's\n")
    os.utime(target, ns=(1_000_000_000_000_000_000, 1_000_000_000_000_000_000))
    return target, target.read_bytes(), target.stat().st_mtime_ns


def unchanged(target: Path, content: bytes, mtime: int) -> bool:
    return target.read_bytes() == content and target.stat().st_mtime_ns == mtime


def snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


# --- hypa.core.folders ---------------------------------------------------------------------------------------------


def test_a_held_folder_refuses_a_second_claim_until_released(tmp_path: Path) -> None:
    folder = tmp_path / "out"
    held = take(folder, "hypa diagnose")
    assert (folder / ".lock").read_text() == f"pid {os.getpid()} on {socket.gethostname()} (hypa diagnose)\n"
    with pytest.raises(FolderRefused) as refused:  # flock: per open file description, so this process conflicts too
        take(folder, "hypa export")
    assert str(refused.value) == (f"{folder} is being written by another hypa diagnose (pid {os.getpid()} on "
                                  f"{socket.gethostname()}); give hypa export its own folder (hydra.run.dir=...) or "
                                  "wait for that one to end")
    held.release()
    with claim(folder, "hypa export") as claimed:
        assert claimed == folder and "(hypa export)" in (folder / ".lock").read_text()


def test_a_lock_file_that_is_a_link_is_never_opened_through(tmp_path: Path) -> None:
    target, content, mtime = outside(tmp_path)
    folder = tmp_path / "run"
    folder.mkdir()
    (folder / ".lock").symlink_to(target)
    with pytest.raises(FolderRefused, match=rf"^{re.escape(str(folder / '.lock'))} is a symbolic link \(to "):
        take(folder, "hypa train")
    (folder / ".lock").unlink()
    os.link(target, folder / ".lock")  # a hard link would be truncated just the same
    with pytest.raises(FolderRefused, match="is not a plain file of its own"):
        take(folder, "hypa train")
    assert unchanged(target, content, mtime)


@pytest.mark.parametrize("link, to_folder", [
    ("train.log", False), ("evaluation", True), ("evaluation/summary.md", False), ("a/b/c/deep.png", False),
    ("", True),  # the folder itself
])
def test_a_folder_that_holds_a_link_is_refused(link: str, to_folder: bool, tmp_path: Path) -> None:
    target, content, mtime = outside(tmp_path)
    folder = tmp_path / "received"
    path = folder / link if link else folder
    path.parent.mkdir(parents=True, exist_ok=True)
    path.symlink_to(target.parent if to_folder else target)
    with pytest.raises(FolderRefused) as refused:
        take(folder, "hypa evaluate", setting="out")
    assert str(refused.value).startswith(f"{path} is a symbolic link (to {target.parent if to_folder else target}): "
                                         "hypa evaluate writes nothing through a link; remove the link, or give "
                                         "hypa evaluate a new folder (out=...)")
    assert unchanged(target, content, mtime) and sorted(p.name for p in target.parent.iterdir()) == ["precious.txt"]


def test_a_file_is_not_a_folder_and_a_huge_folder_is_not_walked(tmp_path: Path) -> None:
    file = tmp_path / "a-file"
    file.write_text("mine")
    with pytest.raises(FolderRefused, match=rf"^out={re.escape(str(file))} is a file, not a folder; give "):
        take(file, "hypa evaluate", setting="out")
    assert file.read_text() == "mine"
    from hypa.core.folders import refuse_links

    for i in range(5):
        (tmp_path / f"f{i}").write_text("")
    with pytest.raises(FolderRefused, match="holds more than 3 files and folders"):
        refuse_links(tmp_path, "hypa export", limit=3)


def test_an_atomic_write_follows_no_link(tmp_path: Path, monkeypatch) -> None:
    target, content, mtime = outside(tmp_path)
    report = tmp_path / "summary.md"
    report.symlink_to(target)  # the file's own name: replaced by the new file, the target untouched
    write_text_atomic(report, "new report\n")
    assert not report.is_symlink() and report.read_text() == "new report\n" and unchanged(target, content, mtime)
    import hypa.core.folders

    monkeypatch.setattr(hypa.core.folders.secrets, "token_hex", lambda n: "guessed")
    placed = tmp_path / f".run.json.{os.getpid()}.guessed.tmp"
    placed.symlink_to(target)  # someone placed a link at the temporary name
    with pytest.raises(UserError, match="already exists"):
        write_atomic(tmp_path / "run.json", lambda file: file.write(b"{}"))
    assert unchanged(target, content, mtime) and placed.is_symlink() and not (tmp_path / "run.json").exists()


def test_run_folder_names_import_from_where_they_were() -> None:
    from hypa.training.run_folder import write_atomic as from_run_folder
    from hypa.training.run_folder import write_text_atomic as text_from_run_folder

    assert from_run_folder is write_atomic and text_from_run_folder is write_text_atomic


# --- default folder names -------------------------------------------------------------------------------------


CONFIGS = ["train", "diagnose", "evaluate", "export", "explain", "benchmark", "simulate", "reproduce"]


@pytest.mark.parametrize("name", CONFIGS)
def test_two_default_folders_made_in_one_second_differ(name: str) -> None:
    from hydra import compose, initialize_config_dir
    from hydra.core.hydra_config import HydraConfig

    from hypa.commands.config import register_configs

    register_configs()  # the schemas, and the resolvers that name the training run's folder

    def folders() -> list[str]:
        names = []
        with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
            for _ in range(2):
                cfg = compose(config_name=name, overrides=["run=x"] if name in ("evaluate", "export", "explain")
                              else [], return_hydra_config=True)
                HydraConfig.instance().set_config(cfg)  # ${hydra:runtime.choices.dataset} in the benchmark's
                names += [str(cfg.hydra.run.dir)] + ([str(cfg.hydra.sweep.dir)] if name in ("train", "diagnose")
                                                       else [])
        return names

    # the stamp carries microseconds: two folders made within one second differ (whether this machine,
    # loaded or not, made these two within one second or not)
    names = folders()
    assert all(re.search(r"\d{4}-\d\d-\d\d_\d\d-\d\d-\d\d-\d{6}$", n) for n in names), names
    half = len(names) // 2
    assert all(a != b for a, b in zip(names[:half], names[half:])), names


# --- the commands ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    return make_data_dir(tmp_path_factory.mktemp("folders") / "data", duration_s=6.0)


@pytest.fixture(scope="module")
def run(tmp_path_factory, data: Path) -> Path:
    """One finished physics-only run (read-only for the tests: they copy it)."""
    folder = tmp_path_factory.mktemp("folders") / "run"
    result = hypa("hypa train", *FAST, f"data.dir={data}", f"hydra.run.dir={folder}", "seed=3")
    assert result.returncode == 0, result.stderr[-3000:]
    return folder


def test_a_run_records_hydra_once_it_holds_its_folder(run: Path) -> None:
    """Hydra's record, written by hypa (hydra.output_subdir: null): the same three files Hydra writes."""
    import yaml

    record = run / ".hydra"
    assert sorted(p.name for p in record.iterdir()) == ["config.yaml", "hydra.yaml", "overrides.yaml"]
    assert yaml.safe_load((record / "config.yaml").read_text())["seed"] == 3
    assert yaml.safe_load((record / "hydra.yaml").read_text())["hydra"]["job"]["name"] == "train"
    assert "seed=3" in yaml.safe_load((record / "overrides.yaml").read_text())
    assert (run / ".lock").read_text().endswith("(hypa train)\n")


def test_a_command_into_a_held_folder_is_refused_and_leaves_it_intact(run: Path, data: Path, tmp_path: Path) -> None:
    """Two commands into one folder: the second (here while the test holds it, as a first command would)
    gets one line and changes nothing there, Hydra's record and log included."""
    commands = {  # hypa.export, hypa.explain and hypa benchmark hold theirs alike (holding_output)
        "hypa diagnose": ["plot=false", "dataset=files", f"data.dir={data}"],
        "hypa train": [*FAST, f"data.dir={data}", "seed=7"],
    }
    held, before, started = [], {}, {}
    for command, arguments in commands.items():
        folder = tmp_path / command
        (folder / ".hydra").mkdir(parents=True)
        for name in ("config.yaml", "hydra.yaml", "overrides.yaml"):
            (folder / ".hydra" / name).write_text(f"the first {command}'s {name}\n")
        (folder / "report.md").write_text("the first one's report\n")
        held.append(take(folder, command))
        before[command] = snapshot(folder)
        started[command] = start(command, *arguments, f"hydra.run.dir={folder}")
    folder = tmp_path / "evaluation"
    held.append(take(folder, "hypa evaluate"))
    before["hypa evaluate"] = snapshot(folder)
    started["hypa evaluate"] = start("hypa evaluate", f"run={run}", f"out={folder}", "tensorboard=false",
                                     f"hydra.run.dir={tmp_path / 'evaluate-hydra'}")
    try:
        for command, process in started.items():
            folder = tmp_path / ("evaluation" if command == "hypa evaluate" else command)
            what = "this run" if command == "hypa train" else command
            setting = "out" if command == "hypa evaluate" else "hydra.run.dir"
            one_line_error(finish(process), command, f"{folder} is being written by another {command} (pid "
                           f"{os.getpid()} on {socket.gethostname()}); give {what} its own folder ({setting}=...) "
                           "or wait for that one to end")
            after = snapshot(folder)
            log = f"{command.split()[-1]}.log"  # Hydra opened it before hypa ran: empty, if there
            assert after.pop(log, b"") == b"" and after == before[command], command
    finally:
        for folder in held:
            folder.release()


def test_no_command_writes_into_a_training_runs_folder(run: Path, data: Path, tmp_path: Path) -> None:
    folder = copy_run(run, tmp_path / "run")
    before = snapshot(folder)
    processes = {  # hypa diagnose and hypa.explain hold theirs as hypa.export does (holding_output)
        "hypa export": start("hypa export", f"run={folder}", f"hydra.run.dir={folder}"),
        "hypa benchmark": start("hypa benchmark", "dataset=silverbox", f"hydra.run.dir={folder}"),
        "hypa evaluate": start("hypa evaluate", f"run={folder}", f"out={folder}", "tensorboard=false",
                               f"hydra.run.dir={tmp_path / 'evaluate-hydra'}"),
    }
    for command, process in processes.items():
        setting = "out" if command == "hypa evaluate" else "hydra.run.dir"
        one_line_error(finish(process), command, f"{folder} is a hypa train run's folder (it holds run.json and "
                       f"checkpoints/): {command} writes nothing into it; give {command} a folder of its own "
                       f"({setting}=...)")
    after = snapshot(folder)
    for command in processes:  # Hydra made each log before hypa ran; nothing was written into them
        assert after.pop(f"{command.split()[-1]}.log", b"") == b""
    assert after == before  # .hydra/, run.json, config.yaml, the checkpoints: the run's own


def test_no_link_in_a_received_folder_is_written_through(run: Path, data: Path, tmp_path: Path) -> None:
    """evaluation/summary.md a link (hypa evaluate), train.log a link (a resumed hypa train): refused in one
    line naming the link, the file outside untouched; out= a file: one line. (evaluation/ itself, .lock:
    below, in this process.)"""
    target, content, mtime = outside(tmp_path)
    report, log = copy_run(run, tmp_path / "report"), copy_run(run, tmp_path / "log")
    (report / "evaluation").mkdir()
    (report / "evaluation" / "summary.md").symlink_to(target)
    (log / "train.log").unlink()
    (log / "train.log").symlink_to(target)
    file = tmp_path / "a-file"
    file.write_text("mine\n")
    cases = [
        (start("hypa evaluate", f"run={report}", "tensorboard=false", f"hydra.run.dir={tmp_path / 'report-hydra'}"),
         "hypa evaluate", f"{report / 'evaluation' / 'summary.md'} is a symbolic link (to {target})"),
        (start("hypa train", *FAST, f"data.dir={data}", "trainer.max_epochs=3",
               f"ckpt_path={log / 'checkpoints' / 'last.ckpt'}", f"hydra.run.dir={tmp_path / 'log-hydra'}"),
         "hypa train", f"{log / 'train.log'} is a symbolic link (to {target})"),
        (start("hypa evaluate", f"run={run}", f"out={file}", "tensorboard=false",
               f"hydra.run.dir={tmp_path / 'file-hydra'}"), "hypa evaluate", f"out={file} is a file, not a folder"),
    ]
    for process, command, message in cases:
        one_line_error(finish(process), command, message)
    assert unchanged(target, content, mtime) and sorted(p.name for p in target.parent.iterdir()) == ["precious.txt"]
    assert file.read_text() == "mine\n"
    assert (log / "run.json").read_text() == (run / "run.json").read_text()  # the resume did not start


@pytest.mark.parametrize("link", [".lock", "train.log", "evaluation"])
def test_a_resumed_run_folder_with_a_link_is_refused(link: str, run: Path, tmp_path: Path) -> None:
    from hypa.training.run_folder import RunFolder

    target, content, mtime = outside(tmp_path)
    folder = copy_run(run, tmp_path / "run")
    (folder / link).unlink(missing_ok=True)
    (folder / link).symlink_to(target.parent if link == "evaluation" else target)
    with (pytest.raises(FolderRefused, match=rf"^{re.escape(str(folder / link))} is a symbolic link"),
          RunFolder.claim(folder, resume=folder / "checkpoints" / "last.ckpt")):
        pytest.fail("claimed")
    assert unchanged(target, content, mtime) and sorted(p.name for p in target.parent.iterdir()) == ["precious.txt"]


def test_a_refused_training_run_leaves_the_first_runs_hydra_record(run: Path, data: Path, tmp_path: Path) -> None:
    """The case that was found: a second hypa train into a run's folder used to replace its .hydra/ (the
    survivor's config recorded the refused run's seed)."""
    folder = copy_run(run, tmp_path / "run")
    before = snapshot(folder)
    result = hypa("hypa train", *FAST, f"data.dir={data}", f"hydra.run.dir={folder}", "seed=7")
    one_line_error(result, "hypa train", "already holds another run's checkpoints")
    after = snapshot(folder)
    assert after.pop(".lock").endswith(b"(hypa train)\n")  # the refused run held the folder to look inside
    assert after == before  # train.log too: the refused run logged nothing
    assert "seed: 3" in (folder / ".hydra" / "config.yaml").read_text()


def test_nested_folders_of_one_evaluation_are_one_claim(run: Path, tmp_path: Path) -> None:
    """hypa evaluate out= its own Hydra folder: held once, not refused as held by itself."""
    out = tmp_path / "both"
    result = hypa("hypa evaluate", f"run={run}", f"out={out}", "tensorboard=false", f"hydra.run.dir={out}")
    assert result.returncode == 0, result.stderr[-3000:]
    assert (out / "summary.md").is_file() and (out / ".hydra" / "overrides.yaml").is_file()
