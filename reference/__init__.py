"""The reference: the chain bits -> FapFrames -> FaceState -> images (:mod:`.pipeline`), which
writes the goldens, and the bundled reference decoder program that runs it (:mod:`.decoder`)."""
