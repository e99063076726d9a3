"""The virtual printer: firmware model and simulated hardware, wired together."""
