"""A two-pass lobe plan with a ``[polarimetry]`` axis is refused when the plan is read
(ADR 0106, amendment), in either mode, before anything moves: the lobe's second pass is
placed with the camera's noise model and the scalar reduction, which a polarimetric run
does not have. Before the check the first pass ran in full (minutes of retarder steps or
PEM settings) and the second pass then failed to plan.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from instrument.cli import main
from instrument.plans.planfile import PlanError, parse_plan

LOBE_PLAN = """
[plan]
kind = "brdf_in_plane"
name = "glass lobe"
[sample]
name = "glass"
[scan]
theta_i = [50.0]
theta_r = {{ start = 30.0, stop = 70.0, step = 10.0 }}
{lobe}
[acquisition]
detectors = ["{detector}"]
{polarimetry}
"""

DRR = '[polarimetry]\nmode = "drr"\nsteps = 25\n'
PEM = '[polarimetry]\nmode = "pem"\n'


def plan(lobe: str = "lobe = { points = 4 }", polarimetry: str = DRR) -> str:
    detector = "lockin" if 'mode = "pem"' in polarimetry else "power_meter"
    return LOBE_PLAN.format(lobe=lobe, polarimetry=polarimetry, detector=detector)


def fields(text: str) -> set[str]:
    with pytest.raises(PlanError) as err:
        parse_plan(text)
    return {e.path for e in err.value.errors}


@pytest.mark.parametrize("polarimetry", [DRR, PEM], ids=["drr", "pem"])
def test_a_polarimetric_lobe_plan_is_refused_naming_the_lobe(polarimetry):
    with pytest.raises(PlanError) as err:
        parse_plan(plan(polarimetry=polarimetry))
    assert {e.path for e in err.value.errors} == {"scan.lobe"}
    assert "specular = {half_width_deg, step_deg}" in str(err.value)
    # either half alone is a valid plan
    assert parse_plan(plan(lobe="")).polarimetry is not None
    assert parse_plan(plan(polarimetry="")).scan["lobe"] == {"points": 4}


def test_scatterlab_run_refuses_it_before_the_bench_opens(tmp_path: Path, capsys):
    path = tmp_path / "lobe.toml"
    path.write_text(plan(), encoding="utf-8")
    out = tmp_path / "runs"
    assert main(["run", str(path), "--bench", "sim-polarimetric", "--out", str(out),
                 "--quiet"]) == 2
    assert "scan.lobe" in capsys.readouterr().err
    assert not list(out.glob("*.h5"))  # no first pass was run


lobe_tables = st.fixed_dictionaries(
    {"points": st.integers(1, 10000)},
    optional={"step_deg": st.floats(0.01, 10.0), "search_half_width_deg": st.floats(0.5, 45.0),
              "search_step_deg": st.floats(0.05, 10.0),
              "prior": st.sampled_from(["ggx", "phong"])})
drr_tables = st.fixed_dictionaries(
    {"mode": st.just("drr")},
    optional={"steps": st.sampled_from([23, 25, 36, 72]), "ratio": st.sampled_from([5, -5, 3.5])})
pem_tables = st.fixed_dictionaries(
    {"mode": st.just("pem")},
    optional={"amplitude_waves": st.floats(0.05, 1.0), "reads": st.integers(4, 100),
              "time_constants": st.floats(1.0, 100.0)})


def value(v: object) -> str:
    """A TOML scalar."""
    return f'"{v}"' if isinstance(v, str) else repr(v)


def toml_inline(table: dict[str, object]) -> str:
    return "{ " + ", ".join(f"{k} = {value(v)}" for k, v in table.items()) + " }"


@settings(max_examples=60, deadline=None)
@given(lobe=lobe_tables, pol=st.one_of(drr_tables, pem_tables))
def test_any_valid_lobe_with_any_valid_polarimetry_table_is_refused_by_that_field(lobe, pol):
    body = "\n".join(f"{k} = {value(v)}" for k, v in pol.items())
    text = plan(lobe=f"lobe = {toml_inline(lobe)}", polarimetry=f"[polarimetry]\n{body}\n")
    assert fields(text) == {"scan.lobe"}
    # without the polarimetry axis the same lobe table is a valid plan, and the same
    # polarimetry table without the lobe
    assert parse_plan(plan(lobe=f"lobe = {toml_inline(lobe)}", polarimetry="")) is not None
    assert parse_plan(plan(lobe="", polarimetry=f"[polarimetry]\n{body}\n")) is not None
