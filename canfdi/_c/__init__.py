"""The C core's sources (C99; see README.md here). Nothing to import: the extension built from
them is canfdi._ckernel, reached through canfdi.core.kernel."""
