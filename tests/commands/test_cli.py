"""``hypa <command>``: one entry for every command, and the spellings from before it (one release,
each with one deprecation line)."""

from __future__ import annotations

import subprocess
import sys
import warnings
from pathlib import Path

import pytest

from hypa.commands.cli import COMMANDS, main

from conftest import ROOT


def python(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, *args], cwd=ROOT, capture_output=True, text=True, timeout=300, check=False)


def test_the_list_of_commands_and_an_unknown_one(capsys) -> None:
    assert main(["--help"]) == 0
    listed = capsys.readouterr().out
    assert all(f"  {name} " in listed for name in COMMANDS)
    assert main([]) == 2  # nothing asked: the list, and the status of a usage error
    assert main(["trian"]) == 2
    error = capsys.readouterr().err.strip()
    assert error.count("\n") == 0 and error.startswith("hypa: error: unknown command 'trian'")


def test_every_command_module_has_the_one_shape() -> None:
    """Each command's module runs alone (`python -m hypa.commands.<module>`) and has main(argv) -> status."""
    import importlib
    import inspect

    for command in COMMANDS.values():
        module = importlib.import_module(f"hypa.commands.{command.module}")
        assert list(inspect.signature(module.main).parameters) == ["argv"], command.module
        assert 'if __name__ == "__main__":\n    sys.exit(main())' in Path(module.__file__).read_text(), command.module


def test_importing_the_commands_registers_nothing() -> None:
    """The schemas and resolvers are registered by a command, not by an import (hypa.commands.config); the
    list of commands (hypa --help) imports neither torch nor the configurations."""
    code = ("import sys\nimport hypa.commands.cli\nassert 'torch' not in sys.modules, 'torch imported'\n"
            "assert 'hypa.commands.config' not in sys.modules, 'the configurations imported'\n"
            "import hypa.commands.train, hypa.commands.config\n"
            "from hydra.core.config_store import ConfigStore\nfrom omegaconf import OmegaConf\n"
            "assert 'hypa' not in ConfigStore.instance().repo, 'schemas stored on import'\n"
            "assert not OmegaConf.has_resolver('run_name') and not OmegaConf.has_resolver('channels')\n"
            "hypa.commands.config.register_configs()\nhypa.commands.config.register_configs()  # idempotent\n"
            "assert 'train_schema.yaml' in ConfigStore.instance().repo['hypa'] and OmegaConf.has_resolver('channels')")
    result = python("-c", code)
    assert result.returncode == 0, result.stderr[-3000:]


def test_every_hydra_command_registers_before_it_composes(capsys, monkeypatch) -> None:
    """With nothing registered, each Hydra command's main composes its configuration (``--cfg job``)."""
    import importlib

    from hydra.core.config_store import ConfigStore
    from omegaconf import OmegaConf

    from hypa.commands.config import RESOLVERS, register_configs

    monkeypatch.setattr(sys, "argv", list(sys.argv))  # each main sets sys.argv to its overrides
    try:
        for name, command in COMMANDS.items():
            module = importlib.import_module(f"hypa.commands.{command.module}")
            if not hasattr(module.main, "job"):  # fleet, timing: options, no Hydra configuration
                continue
            ConfigStore.instance().repo.pop("hypa", None)
            for resolver in RESOLVERS:
                OmegaConf.clear_resolver(resolver)
            assert module.main(["--cfg", "job", *(["run=x"] if name in ("evaluate", "export", "explain") else [])]) == 0
            assert capsys.readouterr().out.strip(), name
            assert "train_schema.yaml" in ConfigStore.instance().repo["hypa"] and OmegaConf.has_resolver("run_name")
    finally:
        register_configs()


def test_python_m_hypa_runs_a_command_and_its_part() -> None:
    bad = python("-m", "hypa", "timing", "physic")
    assert bad.returncode == 2 and bad.stderr.strip().count("\n") == 0 and "physics, diagnosis" in bad.stderr
    helped = python("-m", "hypa", "timing", "physics", "--help")
    assert helped.returncode == 0 and "--scheduled-only" in helped.stdout and helped.stderr == ""
    hydra = python("-m", "hypa", "simulate", "--help")
    assert hydra.returncode == 0 and "simulate is powered by Hydra" in hydra.stdout and hydra.stderr == ""


@pytest.mark.parametrize(("old", "new", "shown"), [
    (["-m", "hypa.bench", "--help"], "hypa timing physics", "--scheduled-only"),
    (["-m", "hypa.bench_diagnosis", "--help"], "hypa timing diagnosis", "--seconds"),
    (["-m", "hypa.speed", "physics", "--help"], "hypa timing", "--scheduled-only"),
    (["-m", "hypa.simulate", "--help"], "hypa simulate", "powered by Hydra"),
    (["-m", "hypa.explain", "--help"], "hypa explain", "powered by Hydra"),
    (["-m", "hypa.diagnosis.fleet", "--help"], "hypa fleet", "summary"),
])
def test_the_former_spellings_run_with_one_deprecation_line(old: list[str], new: str, shown: str) -> None:
    result = python(*old)
    assert result.returncode == 0, result.stderr
    assert shown in result.stdout
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "deprecated" in lines[0] and f"`{new}`" in lines[0], result.stderr


def test_a_moved_module_is_the_module_itself_with_a_warning() -> None:
    import hypa.core.errors

    sys.modules.pop("hypa.errors", None)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        import hypa.errors
    assert sys.modules["hypa.errors"] is hypa.core.errors
    assert next(str(w.message) for w in caught if w.category is DeprecationWarning).startswith(
        "hypa.errors is hypa.core.errors now")
    sys.modules.pop("hypa.errors")


def test_a_former_command_module_is_not_imported() -> None:
    with pytest.raises(ImportError, match="the command is `hypa train`"):
        __import__("hypa.train")
