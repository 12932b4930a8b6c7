"""Protocol-accurate device emulators and fault injectors used by the tests."""
