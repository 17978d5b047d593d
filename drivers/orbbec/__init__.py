"""Orbbec SDK v2 cameras (Femto Bolt / Mega, Gemini) through the SDK's C library: sdk (ctypes), camera (the backend)."""
