"""A trained run: the run configuration, the label space, the scene normalisation, the run folder, the
panoptic model with its loss terms, and the loaded run of ``lift3d.load_run`` (:mod:`lift3d.model.run`).

Above the field and the renderer, below training, evaluation, export and pictures (docs/architecture.md).
The modules are imported one by one (``from lift3d.model.run import load_run``); this package imports
nothing itself.
"""
