"""Device interfaces and drivers (layer 2): camera, stage, LED array, SLM.

Imports nothing of ours (see ARCHITECTURE.md). The device interfaces arrive with
the device/virtual-bench issue.
"""
