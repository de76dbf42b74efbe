"""The `paintjax` console script: one sub-command per module (`_simulate.py` for `paintjax simulate`, …).

In: command-line arguments. Out: tables or JSON on stdout, progress on stderr, results (JSON,
figures) under `--out`. Each command is a thin shell over the library (`paintjax.simulate`,
`paintjax.inverse`, …); bad input gets a one-line error naming the option (exit status 2).
"""

from ._main import main
