"""List attached SR3000-style cameras: bus, address, serial, firmware and register settings.

With --emulate, lists one emulated camera instead (the one `tofd run --emulate` uses).
"""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--emulate", action="store_true", help="list an emulated camera instead of the USB bus")


def main(args: argparse.Namespace) -> int:
    from tofd.drivers.usb.camera import list_devices

    backend = None
    if args.emulate:
        from tofd.drivers.emulator.backend import EmulatorBackend

        backend = EmulatorBackend()
    listings = list_devices(backend)
    if not listings:
        print("no SR3000-style camera (USB 0852:0074) attached; check the cable and the camera's power.")
        return 1
    print(f"{'bus':>3} {'addr':>4}  {'serial':8}  {'firmware':8}  settings")
    for d in listings:
        r = d.registers
        if d.error is not None or r is None:
            print(f"{d.bus:>3} {d.address:>4}  {'?':8}  {'?':8}  cannot query: {d.error}")
            continue
        settings = (f"integration {r.integration_time_s * 1e3:.1f} ms (code {r.int_time_code}), "
                    f"modulation {r.mod_freq_hz / 1e6:g} MHz (index {r.mod_freq_index}), "
                    f"{'test pattern' if r.data_source == 1 else 'scene'}, acq_mode 0x{r.acq_mode:02X}")
        print(f"{d.bus:>3} {d.address:>4}  {d.serial:8}  {d.firmware:8}  {settings}")
    return 0 if all(d.error is None for d in listings) else 1
