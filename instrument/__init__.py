"""The bench (layer 3): configuration, device registry, plan runner, storage, CLI.

May import ``drivers`` and ``recon`` (see docs/architecture.md).
"""
