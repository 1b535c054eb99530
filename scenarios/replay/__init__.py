"""``horizon-nav replay``: a flight log through the vision front end, the filter and the smoother
(docs/replay.md). Modules: :mod:`.inputs` (log -> filter inputs), :mod:`.vision_worker` (vision in
worker processes), :mod:`.pipeline` (the run), :mod:`.solution_log` (solution MCAP),
:mod:`.summary` (figures and table), :mod:`.rerun_view` (Rerun recording and blueprint)."""
