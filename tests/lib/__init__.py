"""Helpers the test tiers share (``from lib.<module> import …``; tests/ is on the import path
through its conftest): manifests of decoders under test, the sandbox markers, hostile decoder
programs, random codec sequences. A test module never imports another test module."""
