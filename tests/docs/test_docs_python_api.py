"""docs/python-api.md runs: its ```python blocks, in order, in one namespace, and the figures the
page quotes hold (the identified mass, the free-run errors, the diagnosis naming the hidden spring).

Steps 1-6 run in every test session (about 15 s on 2 cores); the diagnosis (step 7, the last
block, about 10 s more) is marked slow.
"""

from __future__ import annotations

import re
import tempfile
from pathlib import Path

import numpy as np
import pytest

from conftest import ROOT

PAGE = ROOT / "docs" / "python-api.md"
STEPS = 7  # one python block per step


def python_blocks() -> list[str]:
    blocks = re.findall(r"^```python\n(.*?)^```", PAGE.read_text(), flags=re.DOTALL | re.MULTILINE)
    assert len(blocks) == STEPS, f"{PAGE.name}: {len(blocks)} python blocks, expected one per step ({STEPS})"
    return blocks


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    """A temporary working directory that also holds the page's temporary folder."""
    work = tmp_path_factory.mktemp("python_api")
    with pytest.MonkeyPatch.context() as patch:
        patch.chdir(work)
        patch.setattr(tempfile, "tempdir", str(work))
        yield work


def run(blocks: list[str], namespace: dict, first: int) -> None:
    for k, block in enumerate(blocks, first):
        exec(compile(block, f"{PAGE.name}, python block {k}", "exec"), namespace)  # noqa: S102 -- the page's own code blocks


@pytest.fixture(scope="module")
def page(workdir) -> dict:
    """The page's namespace after steps 1-6 (every block but the diagnosis)."""
    namespace: dict = {"__name__": "python_api_page"}
    run(python_blocks()[:-1], namespace, 1)
    return namespace


@pytest.fixture(scope="module")
def diagnosed(page: dict) -> dict:
    """The namespace after the last block too (step 7, the diagnosis)."""
    run(python_blocks()[-1:], page, STEPS)
    return page


def test_the_records_are_written_and_read_in_si(page: dict, workdir: Path) -> None:
    dm = page["dm"]
    assert page["folder"].parent == workdir and sorted(p.name for p in page["folder"].iterdir()) == \
        ["test.csv", "train.csv", "val.csv"]
    assert (dm.input_names, dm.output_names, dm.dt) == (("force",), ("position",), pytest.approx(0.02))
    position = dm.channels["position"]
    assert (position.unit, position.display_unit, position.display_factor) == ("m", "mm", pytest.approx(1000))
    assert np.std(page["test"]["position"]) == pytest.approx(0.038, rel=0.05)  # the page: 38 mm RMS


def test_identification_finds_the_mass_and_a_stiffer_linear_spring(page: dict) -> None:
    result = page["result"]
    values = result.values()
    assert result.converged and result.warnings == () and set(values) == {"mass", "stiffness", "damping"}
    assert values["mass"] == pytest.approx(page["MASS"], rel=0.05)  # the page: 0.977 kg
    assert values["stiffness"] > page["STIFFNESS"] * 1.05  # the linear stand-in for the stiffening spring
    assert values["damping"] > page["DAMPING"]
    assert all(e.std is not None and 0 < e.std < 0.1 * e.value for e in result.estimates)
    assert result.error_final < 0.1 * result.error_initial
    assert "| mass | 1.3 |" in result.markdown()


def test_free_runs_improve_from_nominal_to_identified_to_hybrid(page: dict) -> None:
    rms = {name: e["rmse"] for name, e in page["scores"].items()}
    assert list(rms) == ["nominal physics", "identified physics", "hybrid"]
    assert all(np.isfinite(v) for v in rms.values())
    assert rms["nominal physics"] == pytest.approx(0.0424, rel=0.05)  # the page: 42.4 mm
    assert rms["identified physics"] == pytest.approx(0.00665, rel=0.05)  # the page: 6.65 mm
    assert rms["hybrid"] < 0.85 * rms["identified physics"]  # the page: 4.74 mm


def test_the_models_are_built_from_what_the_data_module_knows(page: dict) -> None:
    """No statistics, names or sample times copied by hand: ``from_data`` takes them from ``dm``."""
    assert "state_dict()" not in PAGE.read_text()
    dm, module = page["dm"], page["module"]
    assert module.hparams.normalization == dm.normalization.state_dict()
    assert (module.hparams.horizon, module.hparams.past, module.hparams.hold) == (dm.window, dm.past, "foh")
    assert page["model"].hold == "foh" and page["model"].input_names == dm.input_names


@pytest.mark.slow
def test_diagnosis_names_the_hidden_stiffening_spring(diagnosed: dict) -> None:
    search = diagnosed["search"]
    named = [(f.cause, f.target) for f in search.named]
    assert named == [("stiffening_spring", "oscillator"), ("parameter_mismatch", "stiffness")], named
    values = {k.split("/")[-1]: v for f in search.named for k, v in f.values.items()}
    assert values["hardening"] == pytest.approx(diagnosed["HARDENING"], rel=0.1)  # the page: 31.6 1/m^2
    assert values["stiffness"] == pytest.approx(diagnosed["STIFFNESS"], rel=0.05)  # the page: 98.4 N/m
    assert search.final_score < 0.2 * search.nominal_score  # the page: 5.29 % -> 0.76 %
