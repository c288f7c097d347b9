"""The Monte Carlo library behind ``fcmpc-montecarlo``: runs, engines, sweeps, tables, plots.

    runs.py         one run as a pure function of (scenario, settings, seed): RunSpec -> RunRow
    engines.py      where runs go: local process pool (default), Dask (the cluster extra), Ray
    batch.py        the paper's tables: every controller on the same seeds
    tables.py       per-controller summaries beside the paper's figures (Tables 5-7)
    budget.py       the realistic world's error budget
    sweep.py        --sweep axes, the cross product, resumable runs; store.py: Parquet per run
    cli_sweep.py    the sweep's command flow; plots.py, sweep_plots.py: figures

Nothing here is imported by ``companion`` or ``sitl``; :mod:`fcmpc.montecarlo.cli` is the
command line.
"""
