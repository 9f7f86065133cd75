"""``scatterlab devices``: open every device of a bench and say what it is and where;
``--list-drivers``: the drivers a profile may name, built-in and plugins, and where each
comes from."""

from __future__ import annotations

import argparse

HELP = "list the bench's devices: identity, state, position"


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("devices", help=HELP)
    p.add_argument("--bench", default="sim", help="profile name or path (default: sim)")
    p.add_argument("--home", action="store_true", help="home every axis first")
    p.add_argument("--list-drivers", action="store_true",
                   help="list the registered drivers (built-in and plugins: kind, "
                        "distribution and version) instead of opening a bench")
    p.set_defaults(func=run)


def list_drivers() -> int:
    """Print every registered driver and every refused registration; 1 if any was refused."""
    from instrument.bench.driver_registry import load_registry

    registry = load_registry()
    registry.verify()  # import each class: a broken one is reported, not listed as usable
    rows = [(d.name, d.kind, d.origin, "built-in" if d.builtin else "plugin",
             d.entry.emulator.scheme + "://" if d.entry.emulator else "", d.entry.summary)
            for d in (registry.drivers[n] for n in registry.names())]
    head = ("driver", "kind", "from", "", "emulator", "")
    widths = [max(len(r[i]) for r in [*rows, head]) for i in range(5)]
    print("  ".join(h.ljust(w) for h, w in zip(head, widths, strict=False)).rstrip())
    for row in rows:
        cells = [c.ljust(w) for c, w in zip(row, widths, strict=False)]
        print("  ".join([*cells, row[5]]).rstrip())
    if registry.problems:
        print(f"\n{len(registry.problems)} driver registration(s) refused (the drivers above "
              "load regardless):")
        for problem in registry.problems:
            print(f"  {problem}")
        return 1
    return 0


def describe(device: object) -> str:
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

    if args.list_drivers:
        return list_drivers()
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
