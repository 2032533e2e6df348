"""Logs: canfdi's MCAP and every format python-can reads and writes.

``formats`` maps a file name to its format (the one registry, by suffix) and ``logs`` reads
and writes any of them; ``pycan`` adapts python-can's readers and writers, and ``pycan_mcap``
is the other way round: python-can's plugin for canfdi's MCAP. canfdi's own MCAP: ``schemas``
(topics, encodings, JSON schemas), ``blocks`` (messages to and from arrays), ``segments``
(rotated files), ``writer`` (McapRecorder), ``scan`` (the one record walker: CRCs checked,
damaged chunks skipped and resynchronised after), ``damage`` (what a damaged log lost),
``reader`` (messages, metadata, frames, samples, residuals).
"""
