"""File formats, metadata and input validation (see ``docs/formats.md``)."""
