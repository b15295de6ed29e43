"""Decode and render speed against a level's minimum rates: the content made fresh per
measurement (:mod:`.content`), the measurement (:mod:`.measure`), its outputs judged on content
(:mod:`.check`), the machine's load read beside it (:mod:`.load`), and the ``bench`` verb
(:mod:`.bench`)."""
