"""The dataset: the on-disk contract, the viewpoint sphere, the writer, its launchers and verify.

Owns: the contract between the generator and every reader (``contract``: paths, dtypes, the manifest
and annotation readers, numpy only), the camera viewpoint sphere (``sphere``), the run that renders
and resumes a dataset (``writer``: the dataset spec, frame layout and protocol, the grasps file, chunks
of frames rendered in worker processes, locks and resume), the Ray launcher (``ray_launcher``, handed a chunk-renderer
factory) and the re-check of a finished dataset (``verify``).

May import: ``hupbench.datagen.assets``, ``hupbench.datagen.render``, the shared modules at the top of ``datagen``.
Never ``hupbench.datagen.grasps`` (the writer reads a grasps file), ``models`` or ``hupbench``. Readers in
``hupbench`` import ``contract`` only, which pulls in neither the renderer nor the assets.
"""
