"""Byte formats: on-card, on-chip, on-wire and in-flash. Pure: bytes in, objects out."""
