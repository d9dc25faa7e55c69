"""Transports that put a simulated arm where a host reaches a real one: a pseudo-terminal
(`pty`) for a serial bus."""
