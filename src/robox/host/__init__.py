"""Talking to a printer: transports, client API, job sender."""
