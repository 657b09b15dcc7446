"""The verbs that make data and run the pipeline, as functions of their composed Hydra config.

Owns: ``generate`` (``run_generate``), ``grasps`` (``run_grasps``,
``run_train_grasp_sampler``) and ``quickstart`` (``run_quickstart``: every stage, each the same code
as its own verb). ``hupbench.cli`` parses the command line and calls them.

May import: everything below it: ``datagen``, ``hupbench.training``, ``hupbench.evaluation``,
``hupbench.inference`` and the ``hupbench`` top-level modules. Nothing imports it but the CLI.
"""
