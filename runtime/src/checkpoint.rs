//! Checkpoint files: atomic, versioned, checksummed.
