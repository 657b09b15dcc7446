"""The dataset: the viewpoint sphere, the writer, its launchers, and a finished dataset's verify, import and export.

Owns: the camera viewpoint sphere (``sphere``), the run that renders
and resumes a dataset (``writer``: the dataset spec, frame layout and protocol, the grasps file, chunks
of frames rendered in worker processes, locks and resume), the Ray launcher (``ray_launcher``, handed a chunk-renderer
factory), and what is done with a dataset on disk: its re-check (``verify``, ``verify_frames``, ``verify_images``,
``sample_sheet``), the import of the published HUP-3D layout (``import_hup3d``) and the export to BOP and COCO
(``export_bop_coco``); and a scan over time for clips of frames: the probe's moves on the skin (``scan_motion``)
and the wearer's head (``head_motion``), joined on the clinic world into a clip's cameras and labels (``clips``).

The contract between the generator and every reader (paths, dtypes, the manifest and annotation readers) is
the core's (``hupbench.core.contract``).

May import: ``hupbench.core``, ``hupbench.datagen.assets``, ``hupbench.datagen.render``. Never
``hupbench.datagen.grasps`` (the writer reads a grasps file), ``models`` or the rest of ``hupbench``.
"""
