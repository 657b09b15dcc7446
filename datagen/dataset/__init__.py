"""The dataset: the viewpoint sphere, the writer, its launchers and verify.

Owns: the camera viewpoint sphere (``sphere``), the run that renders
and resumes a dataset (``writer``: the dataset spec, frame layout and protocol, the grasps file, chunks
of frames rendered in worker processes, locks and resume), the Ray launcher (``ray_launcher``, handed a chunk-renderer
factory) and the re-check of a finished dataset (``verify``).

The contract between the generator and every reader (paths, dtypes, the manifest and annotation readers) is
the core's (``hupbench.core.contract``).

May import: ``hupbench.core``, ``hupbench.datagen.assets``, ``hupbench.datagen.render``. Never
``hupbench.datagen.grasps`` (the writer reads a grasps file), ``models`` or the rest of ``hupbench``.
"""
