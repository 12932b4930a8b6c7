"""Sphinx extension: the benchmark pages, generated from stored benchmark output.

Each directory under ``docs/benchmarks/results/`` is the ``--out`` directory of one
``python -m benchmarks`` run (or of a ``diffuserlab benchmark`` command);
:func:`benchmarks.report.markdown_page` turns it into
``docs/benchmarks/run-<name>.md`` when the build starts (those files are generated,
not kept in git).
"""

from pathlib import Path


def _generate(app) -> None:
    from benchmarks.report import markdown_page

    here = Path(app.srcdir) / "benchmarks"
    for run in sorted((here / "results").iterdir()):
        if run.is_dir():
            title = (run / "TITLE").read_text().strip() if (run / "TITLE").is_file() \
                else f"Benchmarks: {run.name}"
            page = markdown_page(run, title, figures_prefix=f"results/{run.name}/")
            target = here / f"run-{run.name}.md"
            if not target.is_file() or target.read_text() != page:
                target.write_text(page)


def setup(app):
    app.connect("builder-inited", _generate)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
