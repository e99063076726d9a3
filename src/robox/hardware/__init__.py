"""Simulated peripherals the firmware model drives, and fault injection."""
