"""Logs: canfdi's MCAP and every format python-can reads and writes.

``formats`` maps a file name to its format (the one registry, by suffix) and ``logs`` reads
and writes any of them; ``pycan`` adapts python-can's readers and writers, and ``pycan_mcap``
is the other way round: python-can's plugin for canfdi's MCAP. canfdi's own MCAP:

- topics: ``schemas`` (topics, encodings, JSON schemas), ``rowtopics`` (the registry of row
  topics: adding one is a schema and a `register_row_topic` line), ``blocks`` (messages to and
  from arrays);
- writing: ``writer`` (`McapRecorder`, composing the parts below with the live tap),
  ``channels`` (`Channel`: one topic's rows, buffered and encoded), ``framebuffer`` (raw frames
  packed for their block), ``topicwrites`` (the recorder's write methods), ``segmented``
  (`SegmentedFile`: flushes, rotation, disk full), ``segments`` (the rotated files' names),
  ``mcapwrite`` (mcap's writer as the recorder drives it), ``loghandler`` (Python logging into
  a log), ``retention`` (pruning old logs);
- reading: ``scan`` (the one record walker: CRCs checked, damaged chunks skipped and
  resynchronised after), ``damage`` (what a damaged log lost), ``logreader`` (one file's
  messages and metadata), ``framereader`` (raw frames as blocks), ``reader`` (one generic row
  reader, `read_rows`, and the names built on it: samples, residuals), ``chunkorder`` (the
  order a log's chunks are read in). ``memostore`` keeps what canfdi.core.memo remembers.
"""
