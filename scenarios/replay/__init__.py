"""``horizon-nav replay``: a flight log through the vision front end, the filter and the smoother
(docs/replay.md). Modules: :mod:`.steps` (the steps as Python functions: ``read_flight``, ``see``,
``initialise``, ``navigate``, ``smooth``; exported by :mod:`scenarios`), :mod:`.inputs` (log ->
filter inputs), :mod:`.start` (the initial state), :mod:`.sight` (the vectors: the log's or the
vision's), :mod:`.vision_worker` (vision in worker processes), :mod:`.table` (a solution as a
pandas DataFrame), :mod:`.pipeline` (the command's run: solution log, recording, progress),
:mod:`.solution_log` (solution MCAP), :mod:`.summary` (figures and table), :mod:`.rerun_view`
(Rerun recording and blueprint)."""
