"""The camera's gain and pixel format are recorded in the run file's instrument metadata
(``/entry/instrument/camera``) and read back: a radiometric calibration holds for these
settings only."""

from __future__ import annotations

from pathlib import Path

from drivers.base import PixelFormat
from hw_mocks.sim.ideal import IdealCamera
from instrument.bench.devices import Bench
from instrument.plans import build_plan, parse_plan
from instrument.run.engine import EngineState
from instrument.run.runfile import read_run
from instrument.run.runner import start_run
from tests.instrument.helpers import ideal_bench

ROOT = Path(__file__).resolve().parents[3]


class GainCamera(IdealCamera):
    """An ideal camera whose gain and pixel format can be set."""

    gain_range = (0.0, 24.0)

    def __init__(self, name: str = "camera", **kwargs) -> None:
        super().__init__(name, **kwargs)
        self._gain = 0.0
        self._format = PixelFormat.MONO12

    def _do_get_gain(self) -> float:
        return self._gain

    def _do_set_gain(self, value: float) -> None:
        self._gain = value

    def _do_get_pixel_format(self) -> PixelFormat:
        return self._format

    def _do_set_pixel_format(self, fmt: PixelFormat) -> None:
        self._format = fmt


def test_gain_and_pixel_format_are_recorded_and_read_back(tmp_path):
    ideal = ideal_bench()
    camera = GainCamera("camera")
    camera.gain = 6.5
    camera.pixel_format = PixelFormat.MONO16
    bench = Bench(ideal.profile, {**ideal.devices, "camera": camera})
    plan = build_plan(parse_plan((ROOT / "examples" / "calibration_dark.toml").read_text()),
                      bench.profile)
    engine = start_run(plan, bench, runs_dir=tmp_path, fsync=False, catalog=False)
    assert engine.run() is EngineState.FINISHED
    run = read_run(engine.store.path)
    recorded = run.identities["camera"]
    assert recorded["pixel_format"] == "MONO16"
    assert float(recorded["gain"]) == 6.5
    assert run.camera_gain() == 6.5


def test_a_run_file_without_the_settings_reads_as_not_recorded(tmp_path):
    ideal = ideal_bench()
    plan = build_plan(parse_plan((ROOT / "examples" / "calibration_dark.toml").read_text()),
                      ideal.profile)
    engine = start_run(plan, ideal, runs_dir=tmp_path, fsync=False, catalog=False)
    assert engine.run() is EngineState.FINISHED
    run = read_run(engine.store.path)
    run.identities["camera"].pop("gain")  # as in a file written before they were recorded
    assert run.camera_gain() is None
