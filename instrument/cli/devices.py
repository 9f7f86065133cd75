"""``scatterlab devices``: open every device of a bench and say what it is and where."""

from __future__ import annotations

import argparse

HELP = "list the bench's devices: identity, state, position"


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("devices", help=HELP)
    p.add_argument("--bench", default="sim", help="profile name or path (default: sim)")
    p.add_argument("--home", action="store_true", help="home every axis first")
    p.set_defaults(func=run)


def describe(device) -> str:
    """One line of live state for a device."""
    from drivers.base import Camera, LightSource, MotionAxis, PowerMeter

    if isinstance(device, MotionAxis):
        s = device.status()
        homed = "homed" if s.is_homed else "NOT homed"
        moving = ", moving" if s.is_moving else ""
        enabled = "" if s.is_enabled else ", disabled"
        return f"{homed}{enabled}{moving}, position {s.position:.4f} {device.units}"
    if isinstance(device, Camera):
        h, w = device.sensor_shape
        return (f"{w}x{h} px, {device.bit_depth}-bit, exposure {device.exposure_us:g} us, "
                f"gain {device.gain:g}")
    if isinstance(device, PowerMeter):
        return f"wavelength {device.wavelength_nm:g} nm, reading {device.read_power_w():.4e} W"
    if isinstance(device, LightSource):
        return "on" if device.is_on else "off"
    return ""


def run(args: argparse.Namespace) -> int:
    from drivers.errors import DeviceError
    from instrument.bench.devices import open_bench
    from instrument.bench.profile import load_profile

    profile = load_profile(args.bench)
    print(f"bench {profile.name!r}: {profile.description}")
    failures = 0
    with open_bench(profile) as bench:
        if args.home:
            for axis in bench.axes.values():
                axis.enable()
                axis.home(timeout=300.0)
        width = max(len(r) for r in bench.devices)
        for role, device in bench.devices.items():
            spec = profile.device(role)
            try:
                ident = device.identity
                who = f"{ident.vendor} {ident.model} s/n {ident.serial}"
                if ident.firmware:
                    who += f" fw {ident.firmware}"
                state = describe(device)
            except DeviceError as err:
                failures += 1
                who, state = "?", f"ERROR: {err}"
            print(f"  {role:<{width}}  {spec.driver:<15} {spec.url}")
            print(f"  {'':<{width}}  {who}")
            print(f"  {'':<{width}}  {state}")
    return 1 if failures else 0
