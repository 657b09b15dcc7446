"""Evaluation: scoring a model on a dataset split, the results schema and the leaderboard.

Owns: ``hupbench eval`` (``evaluate``: a checkpoint or an ONNX export over a split, with ``prediction``: the one
loop that predicts a split, also used by scripts/; ``split_metrics``: MPJPE by part and the breakdowns, whose
per-frame buckets ``breakdowns`` labels; ``probe_pose``: the BOP scores; ``latency``: parameters, FLOPs and
latency), the results file (``results``:
schema, strict reading, validation, atomic writes) and the leaderboard (``leaderboard``: the verb, its rows and
training logs; ``leaderboard_table``: the cells; ``leaderboard_readme``: the README; ``leaderboard_plots``: the
error-against-time plots; rebuilt from results/).

May import: ``hupbench.inference`` (the ONNX contract and onnxruntime sessions, to time an export),
``hupbench.fits`` (what runs after the network),
``hupbench`` top-level modules (data, checkpoint, metrics, provenance, config, errors), ``models``,
the dataset contract, torch, numpy, matplotlib. Never ``hupbench.training`` or ``hupbench.verbs``.
"""
