"""Scenes: the BT text reader/writer (:mod:`.bt`) and the binary BIFS coder (:mod:`.bifs`), with their
node tables in ``data/``."""
