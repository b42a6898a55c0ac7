"""Benchmarks: the stage-by-stage suite (:mod:`benchmarks.run`), the thesis's published figures
(:mod:`benchmarks.paper`) and per-stage scripts of the engineers who own those stages."""
