"""Training: one loop for every model, and the pieces it is made of.

Owns: the loop (``loop``: ``train(run, folder)`` = setup, steps, validation, checkpoints, summary; ``python
train.py`` calls ``loop.main``), the typed run config (``run_config``: frozen nodes, each checking its
own fields), the loss (``losses``), the learning-rate schedule and epoch order (``schedule``), validation
and batch-norm re-estimation (``validation``), the run's log (``run_log``: metrics.jsonl, TensorBoard,
train.log and the progress bar). The run's inputs come from
:mod:`hupbench.data`.

May import: ``models``, the dataset contract (``hupbench.core.contract``), ``datagen`` shared
modules (keypoints, io), ``hupbench`` top-level modules (config, errors, provenance, checkpoint,
data, metrics), torch, numpy, Hydra/OmegaConf. Never ``hupbench.inference`` or the CLI.
"""
