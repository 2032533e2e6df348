"""Logs: canfdi's MCAP and every format python-can reads and writes.

``formats`` maps a file name to its format (the one registry, by suffix) and ``logs`` reads
and writes any of them; ``pycan`` adapts python-can's readers and writers. canfdi's own MCAP:
``schemas`` (topics, encodings, JSON schemas), ``blocks`` (block messages to and from arrays),
``segments`` (rotated files), ``writer`` (McapRecorder), ``reader`` (messages, metadata,
frames, samples, residuals) and ``scan`` (the fast topic scanner replay uses).
"""
