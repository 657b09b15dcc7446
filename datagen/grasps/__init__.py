"""Grasp synthesis: the two-stage generator of hand poses holding the probe.

Owns: the BPS encoding of the probe (``bps``), the conditional VAE sampler (``cvae``: the network and
its weights file; ``cvae_training``: its corpus and training; ``cvae_sampling``: candidates from the
shipped weights), the approach direction and the generator's frame (``approach``, ``frames``), the
energy-based refinement (``refine``), the grasp scores (``scores``), the parameters (``params``),
the selection of a diverse set (``synthesis``) and the contact sheet (``sheet``).

May import: ``hupbench.datagen.assets`` (the hand and the probe), ``hupbench.datagen.render`` (the contact sheet), the
shared modules at the top of ``datagen``, numpy, scipy, torch. Never ``hupbench.datagen.dataset`` (a dataset
reads the grasps file this package writes), ``models`` or ``hupbench``.
"""
