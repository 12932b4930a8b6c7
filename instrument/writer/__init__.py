"""The one writer of the project's product files: every file a command, the GUI or the
demo writes goes through these modules (the napari widget shows layers and writes
nothing; its reader recognises the volumes written here). Products inside a run
(``recon-run``'s, the calibrations') are the run store's arrays
(``instrument.runs.run_products``).

- :mod:`instrument.writer.guards`: the check every command runs on its outputs before
  any work (never an input, never an existing file without ``--overwrite``, writable;
  :func:`~instrument.writer.guards.check_outputs`).
- :mod:`instrument.writer.files`: the float32 TIFF data product, the 8-bit PNG view,
  ``.npy`` (:func:`~instrument.writer.files.save_image`) and the GUI's snapshot TIFF
  (:func:`~instrument.writer.files.write_snapshot`).
- :mod:`instrument.writer.products`: a reconstruction's products, named from
  ``--out`` and written from its arrays: the image, its view and its metrics JSON; the
  volume (float TIFF or OME-Zarr) and its projections.
- :mod:`instrument.writer.evaluation`: the files of ``holo evaluate``.
- :mod:`instrument.writer.figures`: the figures of ``analyze`` and the benchmarks
  (:func:`~instrument.writer.figures.save_figure`).

The ``runs export`` TIFFs are written by
:func:`~instrument.writer.files.write_tiff_file` with the tags
:func:`instrument.runs.tiff_export.write_tiff` builds; text files other than JSON by
:func:`instrument.atomic.write_text`; an append-only log by
:class:`instrument.atomic.AppendLog`; generated docs pages by
``instrument.writer.docpage``. ``tests/test_one_writer.py`` fails when a module
outside these and the run store writes a file itself.

All of them write through :mod:`instrument.atomic`: outputs whole or not at all (a
temporary name renamed into place, :func:`~instrument.atomic.atomic_path` and
:func:`~instrument.atomic.atomic_dir`), several outputs together
(:func:`~instrument.atomic.output_group`, replacing or taking only free names), a
failed Zarr output removed after zarr's writes in flight, a full disk named with its
free space, and every JSON file (:func:`~instrument.atomic.write_json`). That module
imports nothing else of ``instrument``, so the run stores, which this package reads
(:mod:`instrument.runs.ome` for the volume's OME block, run stores for the guards), write
through it too without an import cycle.

The reconstruction layer (``recon``) writes no files: it returns arrays and records,
and reads its inputs (:mod:`recon.io`). The submodules are imported where they are used
(the command line's start loads none of the image libraries).
"""
