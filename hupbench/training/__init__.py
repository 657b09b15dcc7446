"""Training: one loop for every model, and the pieces it is made of.

Owns: the loop (``loop``: ``train(run)`` = setup, steps, validation, checkpoints, summary, over the typed run;
``python train.py`` and ``hupbench train`` reach it through :mod:`hupbench.verbs.train`), the typed run
config (``run_config``: frozen nodes, each checking its own fields), which checkpoint a run continues
(``resume``), the loss (``losses``), the learning-rate schedule (``schedule``), validation and batch-norm
re-estimation (``validation``), the run's log (``run_log``: metrics.jsonl, TensorBoard, train.log and the
progress bar). The run's inputs come from :mod:`hupbench.data`.

May import: ``models``, the shared core (``hupbench.core``: the dataset contract, keypoints, io, errors,
input checks), ``hupbench`` top-level modules (config, provenance, checkpoint, metrics, input_geometry),
``hupbench.data``, torch, numpy, Hydra/OmegaConf. Never ``hupbench.inference``, ``hupbench.evaluation``,
the verbs or the CLI.
"""
