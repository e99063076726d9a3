"""Offline tools over image and dump files (card images, EEPROM dumps, firmware images)."""
