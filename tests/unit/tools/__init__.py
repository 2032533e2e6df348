"""Unit tests of canfdi.tools, the verbs' library: a file per module or topic."""
