"""The driver registry: built-in and plugin drivers through one entry-point group, and a
broken plugin reported by name while the others load (ADR 0092).

Plugins here are real installed distributions on disk (``fake_dists``), read through
``importlib.metadata`` as pip-installed ones are."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.base import PowerMeter
from drivers.errors import ConnectionFailed
from instrument.bench.devices import open_device
from instrument.bench.driver_registry import (
    KINDS,
    DriverEntry,
    Option,
    driver_registry,
    kind_abc,
    load_registry,
)
from instrument.bench.profile import ProfileError, parse_profile
from tests.plugins.fake_dists import GOOD_MODULE, make_dist, unique

BUILTINS = {"thorlabs_apt": "motion_axis", "newport_smc100": "motion_axis",
            "zaber": "motion_axis", "pm100usb": "power_meter", "opencv_camera": "camera",
            "sim_camera": "camera", "sim_source": "light_source", "sr830": "lockin",
            "sc10": "shutter", "fw102c": "filter_wheel", "basler": "camera"}


@pytest.fixture
def site(tmp_path, monkeypatch):
    """A folder on sys.path for fake distributions; the process's registry is read anew
    with them and again after the test."""
    monkeypatch.syspath_prepend(str(tmp_path))
    driver_registry.cache_clear()
    yield tmp_path
    monkeypatch.undo()
    driver_registry.cache_clear()


def test_the_builtin_drivers_are_registered_through_the_entry_points():
    registry = load_registry()
    assert not registry.problems
    for name, kind in BUILTINS.items():
        found = registry.get(name)
        assert found is not None and found.kind == kind and found.builtin
        assert found.distribution == "scatterlab" and found.version
        assert found.target.startswith("instrument.bench.builtin_drivers:")
    assert registry.verify() == []  # every class imports and is of its kind
    assert registry.emulator_schemes()["simapt"] == "hw_mocks.urlhandler"


def test_the_example_plugin_is_installed_and_registered_like_a_builtin():
    found = load_registry().get("example_meter")
    assert found is not None and not found.builtin
    assert (found.kind, found.distribution, found.version) == (
        "power_meter", "scatterlab-example-meter", "1.0.0")
    assert issubclass(found.driver_class(), PowerMeter)


def test_a_good_plugin_loads_and_a_profile_names_it_like_a_builtin(site):
    module = unique("good_plugin")
    make_dist(site, "lab-meter", "2.3", {"lab_meter": f"{module}:DRIVER"},
              {module: GOOD_MODULE})
    registry = load_registry()
    assert registry.get("lab_meter").origin == "lab-meter 2.3"
    profile = parse_profile('[bench]\nname = "b"\n[devices.pm]\ndriver = "lab_meter"\n'
                            'url = "simem1://pm"\noptions = { reply_timeout = 1 }\n')
    spec = profile.device("pm")
    assert spec.kind == "power_meter" and spec.options == {"reply_timeout": 1.0}
    with open_device(spec) as meter:
        assert meter.identity.model == "EM-1"


def test_a_plugin_camera_found_by_serial_number_is_named_by_serial_like_basler(site):
    module = unique("serial_camera")
    make_dist(site, "lab-camera", "1.0", {"lab_camera": f"{module}:DRIVER"},
              {module: "from instrument.bench.driver_registry import DriverEntry\n"
                       "DRIVER = DriverEntry('camera', 'drivers.opencv_camera:OpenCVCamera',"
                       " by_serial=True)\n"})
    assert driver_registry().serial_drivers() == ["basler", "lab_camera"]
    head = '[bench]\nname = "b"\n[devices.camera]\ndriver = "lab_camera"\n'
    spec = parse_profile(head + 'serial = "AB-1234"\n').device("camera")
    assert (spec.url, spec.kind) == ("AB-1234", "camera")  # the serial stands for the url
    # it is the bench's camera by its kind; its timing, with no default known, is zero
    # and the estimate says to give it
    from instrument.bench.timing import bench_timing

    timing = bench_timing(parse_profile(head + 'serial = "AB-1234"\nframe_overhead_s = 0.1\n'))
    assert (timing.frame_overhead_s, timing.scene_change_s) == (0.1, 0.0)
    assert [a for a in timing.assumed if "lab_camera" in a] == [
        "camera.scene_change_s not in the profile: 0 s assumed (no default for driver "
        "'lab_camera'; give it in the profile)"]
    with pytest.raises(ProfileError) as info:
        parse_profile(head + 'url = "/dev/video0"\n')
    assert {e.path for e in info.value.errors} == {"devices.camera.url",
                                                   "devices.camera.serial"}
    # a driver found at a url is refused a serial, told which drivers take one
    with pytest.raises(ProfileError) as info:
        parse_profile(head.replace("lab_camera", "opencv_camera")
                      + 'url = "/dev/video0"\nserial = "1"\n')
    (error,) = info.value.errors
    assert error.path == "devices.camera.serial"
    assert "basler, lab_camera" in error.message


def _problem(registry, name):
    found = [p for p in registry.problems if p.name == name]
    assert len(found) == 1, registry.problems
    return found[0]


def test_a_plugin_that_does_not_import_is_reported_and_the_others_load(site):
    broken, good = unique("broken_plugin"), unique("good_plugin")
    make_dist(site, "broken-dist", "0.1", {"broken_meter": f"{broken}:DRIVER"},
              {broken: "import a_module_that_is_not_installed\n"})
    make_dist(site, "good-dist", "1.0", {"good_meter": f"{good}:DRIVER"}, {good: GOOD_MODULE})
    registry = load_registry()
    problem = _problem(registry, "broken_meter")
    assert (problem.distribution, problem.version) == ("broken-dist", "0.1")
    assert "does not import" in problem.message and "a_module_that_is_not_installed" in \
        problem.message and "uninstall broken-dist" in problem.message
    assert "broken_meter" in str(problem) and "broken-dist 0.1" in str(problem)
    assert registry.get("good_meter") is not None
    assert set(BUILTINS) <= set(registry.names())
    # a profile naming it is told why, with the plugin's name and distribution
    with pytest.raises(ProfileError) as info:
        parse_profile('[bench]\nname = "b"\n[devices.pm]\ndriver = "broken_meter"\n'
                      'url = "x"\n')
    (error,) = info.value.errors
    assert error.path == "devices.pm.driver"
    assert "not usable" in error.message and "broken-dist" in error.message


def test_a_class_that_is_not_of_its_kind_is_reported_by_name(site):
    module = unique("wrong_abc")
    make_dist(site, "wrong-abc", "1.0",
              {"wrong_class": f"{module}:AS_CLASS", "wrong_string": f"{module}:AS_STRING"},
              {module: "from drivers.base import MotionAxis\n"
                       "from instrument.bench.driver_registry import DriverEntry\n"
                       "AS_CLASS = DriverEntry('power_meter', MotionAxis)\n"
                       f"AS_STRING = DriverEntry('power_meter', '{module}:MotionAxis')\n"})
    registry = load_registry()
    # a class given as such is checked when the registry is read
    problem = _problem(registry, "wrong_class")
    assert "not a subclass of drivers.base.PowerMeter" in problem.message
    assert problem.distribution == "wrong-abc"
    # a "module:Class" is imported when used: opening the device refuses it by name ...
    spec = parse_profile('[bench]\nname = "b"\n[devices.pm]\ndriver = "wrong_string"\n'
                         'url = "x"\n').device("pm")
    with pytest.raises(ConnectionFailed, match=r"wrong_string.*wrong-abc 1\.0.*not a "
                                               r"subclass of drivers\.base\.PowerMeter"):
        open_device(spec)
    # ... and verify() (what --list-drivers runs) moves it to the problems
    assert [p.name for p in registry.verify()] == ["wrong_string"]
    assert registry.get("wrong_string") is None and registry.get("thorlabs_apt") is not None


def test_entry_points_that_are_not_driver_entries_or_name_unknown_kinds_are_reported(site):
    module = unique("odd_plugin")
    make_dist(site, "odd-dist", "1.0",
              {"not_an_entry": f"{module}:NOT_AN_ENTRY", "odd_kind": f"{module}:ODD_KIND"},
              {module: "from instrument.bench.driver_registry import DriverEntry\n"
                       "NOT_AN_ENTRY = {'kind': 'power_meter'}\n"
                       "ODD_KIND = DriverEntry('spectrometer', 'x:Y')\n"})
    registry = load_registry()
    assert "not an instrument.bench.driver_registry.DriverEntry" in \
        _problem(registry, "not_an_entry").message
    assert "unknown device kind 'spectrometer'" in _problem(registry, "odd_kind").message
    assert set(BUILTINS) <= set(registry.names())


def test_a_plugin_reusing_a_builtin_name_is_refused_and_the_builtin_kept(site):
    module = unique("clash")
    make_dist(site, "clash-dist", "1.0", {"pm100usb": f"{module}:DRIVER"},
              {module: GOOD_MODULE})
    registry = load_registry()
    assert registry.get("pm100usb").builtin
    problem = _problem(registry, "pm100usb")
    assert problem.distribution == "clash-dist"
    assert "duplicate driver name" in problem.message and "built-in" in problem.message


def test_two_plugins_with_one_name_are_both_refused_and_the_others_load(site):
    one, two, other = unique("one"), unique("two"), unique("other")
    make_dist(site, "dist-one", "1.0", {"lab_meter": f"{one}:DRIVER",
                                        "other_meter": f"{other}:DRIVER"},
              {one: GOOD_MODULE, other: GOOD_MODULE})
    make_dist(site, "dist-two", "2.0", {"lab_meter": f"{two}:DRIVER"}, {two: GOOD_MODULE})
    registry = load_registry()
    assert registry.get("lab_meter") is None and registry.get("other_meter") is not None
    refused = sorted(p.distribution for p in registry.problems if p.name == "lab_meter")
    assert refused == ["dist-one", "dist-two"]
    assert all("uninstall one of them" in p.message for p in registry.problems)


def test_a_plugins_options_and_settings_are_validated_like_builtin_fields():
    text = ('[bench]\nname = "b"\n[devices.power_meter]\ndriver = "example_meter"\n'
            'url = "simem1://pm"\noptions = {{ {options} }}\nsettings = {{ {settings} }}\n')
    with pytest.raises(ProfileError) as info:
        parse_profile(text.format(options='reply_timeout = 100.0, speed = 3',
                                  settings='wavelength_nm = 200.0, gain = 2'))
    errors = {e.path: e.message for e in info.value.errors}
    assert errors["devices.power_meter.options.reply_timeout"] == \
        "must be a number from 0.01 to 10"
    assert "not an option of driver 'example_meter'" in \
        errors["devices.power_meter.options.speed"]
    assert "reply_timeout" in errors["devices.power_meter.options.speed"]
    assert errors["devices.power_meter.settings.wavelength_nm"] == \
        "must be a number from 300 to 1100"
    assert "not a setting" in errors["devices.power_meter.settings.gain"]
    # a motion-only key on a power meter is refused by its kind, as for a built-in one
    with pytest.raises(ProfileError, match="only motion devices take 'limits'"):
        parse_profile(text.format(options="", settings="") + "limits = [0.0, 1.0]\n")


def test_the_kinds_are_the_abcs_of_drivers_base():
    from drivers import base

    assert all(kind_abc(kind) is getattr(base, name) for kind, name in KINDS.items())
    assert set(KINDS) == {"motion_axis", "camera", "light_source", "shutter", "power_meter",
                          "lockin", "filter_wheel", "modulator"}


numbers = st.one_of(st.integers(-10**9, 10**9), st.floats(allow_nan=True,
                                                          allow_infinity=True))
values = st.one_of(numbers, st.booleans(), st.text(max_size=5), st.none(),
                   st.lists(st.integers(), max_size=2), st.dictionaries(st.text(max_size=2),
                                                                        st.integers()))


@settings(max_examples=300, deadline=None)
@given(value=values, low=st.floats(-1e6, 1e6), width=st.floats(0, 1e6),
       kind=st.sampled_from([float, int, bool, str, dict, list]))
def test_option_accepts_exactly_the_values_of_its_type_and_range(value, low, width, kind):
    option = Option(kind, low, low + width) if kind in (float, int) else Option(kind)
    problem = option.problem(value)  # never raises
    is_number = isinstance(value, int | float) and not isinstance(value, bool)
    if kind is float:
        ok = is_number and math.isfinite(value) and low <= value <= low + width
    elif kind is int:
        ok = isinstance(value, int) and not isinstance(value, bool) and \
            low <= value <= low + width
    else:
        ok = isinstance(value, kind)
    assert (problem is None) == ok
    if problem is not None:
        assert problem.startswith("must be")


def test_an_option_of_an_unsupported_type_is_a_type_error():
    with pytest.raises(TypeError, match="Option type"):
        Option(complex)
    assert DriverEntry("camera", "x:Y").options == {}


def test_the_registrys_kinds_are_the_guis_device_kinds():
    """A plugin's device is shown through the GUI kind of the same name: every registry
    kind is a GUI kind with the same ABC. The GUI's other kinds refine one of them for a
    class with more to set (``genicam_camera``: the ``basler`` driver's class, registered
    as a ``camera``), and the GUI shows a device through the most derived kind."""
    from instrument.bench.device_state import kind_of, kinds

    gui = {k.name: k.base for k in kinds()}
    assert {name: gui.get(name) for name in KINDS} == {name: kind_abc(name) for name in KINDS}
    refined = {name: base for name, base in gui.items() if name not in KINDS}
    assert refined, "the GUI refines the camera kind for GenICam cameras"
    for name, base in refined.items():
        assert any(issubclass(base, kind_abc(k)) for k in KINDS), name
    basler = driver_registry().get("basler")
    assert basler is not None and basler.kind == "camera" and basler.builtin
    cls = basler.driver_class()
    assert issubclass(cls, gui["genicam_camera"])
    device = object.__new__(cls)  # not opened: only its class decides its GUI kind
    assert kind_of(device).name == "genicam_camera"


def test_an_environment_without_scatterlabs_entry_points_is_told_to_reinstall():
    from instrument.bench.driver_registry import DriverRegistry

    message = DriverRegistry().unknown_driver_message("thorlabs_apt")
    assert "entry points are missing" in message and "pip install -e ." in message


@pytest.mark.parametrize(("query", "options", "expected"), [
    ("speed=20", "", (0.05 / 20, 0.2 / 20)),   # the emulated controller's clock
    ("speed=20", "options = { flush_s = 0.3 }\n", (0.05 / 20, 0.3)),  # as the profile says
    ("", "", (0.05, 0.2)),                     # real time: the APT document's pauses
    ("step=0.01", "", (0.05, 0.2)),            # a stepped clock has no speed
])
def test_an_emulated_apt_controller_is_opened_with_its_pauses_in_its_own_time(
        query, options, expected):
    """The open sequence's RTS cycle and in-flight wait are device time (ADR 0115)."""
    profile = parse_profile(
        '[bench]\nname = "b"\n[devices.sample_theta]\ndriver = "thorlabs_apt"\n'
        f'url = "simapt://pace_{unique("apt")}?model=K10CR1&{query}"\n'
        f'stage = "K10CR1"\n{options}')
    with open_device(profile.device("sample_theta")) as axis:
        assert (axis._rts_settle_s, axis._flush_s) == pytest.approx(expected, rel=1e-12)
        assert axis.info is not None and axis.info.model.startswith("K10CR1")
