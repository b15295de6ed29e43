"""The goldens: what the reference writes for every case (data only; ``MANIFEST.json`` lists
each file's digest). Made by ``fbaconf golden regenerate``, checked by ``fbaconf golden verify``."""
