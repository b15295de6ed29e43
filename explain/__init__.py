"""Root causes of a decoder's failures (``fbaconf explain``): the failing cases of a run grouped
into a few causes, ranked by what the failing cases share that the passing ones do not, each
confirmed by a derived input without its trigger that the decoder then passes."""
