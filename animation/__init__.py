"""The animation stage: BT scenes, face models, FaceDefTables, FIT, visemes/expressions,
left/right fill, FDP calibration and the reference animation engine (see docs/animation.md).

Entry point: :func:`fbaconf.animation.engine.animate` (FapFrames + scene -> FaceState).
"""
