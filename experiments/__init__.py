"""The paper reproductions, benchmarks, parameter fits and GPU/MJX checks that go with ``jaxplan``.

Each module is a script: run it from the repository root as ``python -m experiments.NAME [--help]``
(for example ``python -m experiments.table2 --quick``). A run writes its table and its numbers to
``experiments/results/<stem>.md`` and ``<stem>.json`` (``experiments.results_io.write_results``);
``experiments/README.md`` lists the scripts by kind, with their commands and results files, and
docs/benchmarks.md shows the tables beside the papers' figures. This package is not part of the
``jaxplan`` wheel; scripts import the library through its public API and one another as
``experiments.NAME``.
"""
