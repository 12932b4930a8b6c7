"""The bench process and its service: the host that owns the open bench in a process of
its own (devices, camera stream, jobs), its typed service, the client
(``BenchClient``) and its connection file, the jobs it runs by name, a job's handle,
the bench state put back after a run, and the recovery of runs a killed bench
process left open.
"""
