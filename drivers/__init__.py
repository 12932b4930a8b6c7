"""Device interfaces and drivers (layer 2): camera, stage, LED array, SLM.

Imports nothing of ours (see docs/architecture.md).

- :mod:`drivers.errors`: the exception hierarchy (every message names device, problem, fix);
- :mod:`drivers.base`: :class:`~drivers.base.Device`, the shared lifecycle and settings;
- :mod:`drivers.camera`, :mod:`drivers.stage`, :mod:`drivers.led_array`,
  :mod:`drivers.slm`: the interfaces (public methods validate; drivers implement ``_do_*``);
- :mod:`drivers.simulated`: simulated drivers on a shared simulated clock, with faults.
"""
