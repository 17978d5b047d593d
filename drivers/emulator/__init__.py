"""An emulated SR3000-style camera behind a pyusb backend: device model, rendered face scene, camera wiring."""
