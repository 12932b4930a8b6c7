"""What every layer of DiffuserLab shares (layer 0): the error contract and JSON files.

:mod:`diffuserlab.errors` holds the project's root exception and the input-error type
every command turns into exit status 2; :mod:`diffuserlab.jsonio` the one conversion
to JSON types and the one atomic JSON writer. ``recon`` and ``drivers`` (layer 1)
import this package and nothing else of ours; it imports nothing of ours.
"""
