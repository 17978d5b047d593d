"""List the attached cameras of every kind tofd can run on: the SR3000-style USB cameras (bus, address, serial,
firmware and register settings) and the cameras of each installed vendor SDK (model, serial, firmware); says which
SDKs are not installed and the extra that installs each.

With --emulate, lists one emulated SR3000 instead of the USB bus (the one `tofd run --emulate` uses). Exits 0 when
every camera found could be queried (also when none is attached), 1 when one could not.
"""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--emulate", action="store_true", help="list an emulated SR3000 instead of the USB bus")


def _sr3000(emulate: bool) -> bool:
    """Print the SR3000-style cameras; whether each could be queried."""
    from tofd.drivers.usb.camera import list_devices
    from tofd.drivers.usb.errors import NoUsbBackend, UsbCameraError

    backend = None
    if emulate:
        from tofd.drivers.emulator.backend import EmulatorBackend

        backend = EmulatorBackend()
    print("sr3000 (SR3000-style USB cameras, 0852:0074" + (", emulated):" if emulate else "):"))
    try:
        listings = list_devices(backend)
    except NoUsbBackend as exc:
        print(f"  cannot look: {exc}")
        return True
    except UsbCameraError as exc:
        print(f"  cannot enumerate: {exc}")
        return False
    if not listings:
        print("  none attached")
        return True
    print(f"  {'bus':>3} {'addr':>4}  {'serial':8}  {'firmware':8}  settings")
    for d in listings:
        r = d.registers
        if d.error is not None or r is None:
            print(f"  {d.bus:>3} {d.address:>4}  {'?':8}  {'?':8}  cannot query: {d.error}")
            continue
        settings = (f"integration {r.integration_time_s * 1e3:.1f} ms (code {r.int_time_code}), "
                    f"modulation {r.mod_freq_hz / 1e6:g} MHz (index {r.mod_freq_index}), "
                    f"{'test pattern' if r.data_source == 1 else 'scene'}, acq_mode 0x{r.acq_mode:02X}")
        print(f"  {d.bus:>3} {d.address:>4}  {d.serial:8}  {d.firmware:8}  {settings}")
    return all(d.error is None for d in listings)


def _sdk(kind: str) -> bool:
    """Print the cameras of SDK `kind` (or that its SDK is missing); whether they could be listed."""
    from tofd.drivers.cameras import SdkMissing, backend
    from tofd.drivers.source import DriverError

    try:
        cameras = backend(kind).list_cameras()
    except SdkMissing as exc:
        print(f"{kind}: not installed: {exc}")
        return True
    except (DriverError, RuntimeError) as exc:  # the SDK's own errors are RuntimeErrors
        print(f"{kind}:\n  cannot enumerate: {exc}")
        return False
    print(f"{kind}:")
    if not cameras:
        print("  none attached")
        return True
    width = max(len(c.model) for c in cameras)
    print(f"  {'model':{width}}  {'serial':16}  {'firmware':12}  detail")
    for c in cameras:
        print(f"  {c.model:{width}}  {c.serial:16}  {c.firmware:12}  {c.detail}")
    return True


def main(args: argparse.Namespace) -> int:
    from tofd.drivers.cameras import SDK_KINDS

    ok = _sr3000(args.emulate)
    for kind in SDK_KINDS:
        ok = _sdk(kind) and ok
    return 0 if ok else 1
