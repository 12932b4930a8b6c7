"""The bench as devices: from a bench file to open devices by role (the bench file a
command opens, the driver registry, the setup), and the benches without hardware:
the virtual bench (its optical model, its SLM's response, its scenes) and the
emulated bench (the real drivers on protocol emulators).
"""
