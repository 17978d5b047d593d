"""SR3000-style USB cameras through pyusb: wire protocol, device access, error translation, the camera source."""
