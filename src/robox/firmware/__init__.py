"""The Robox firmware model: one module per firmware object."""
