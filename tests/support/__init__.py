"""Helpers the tests share: twins started for a test, transcripts, fixtures written on the fly."""
