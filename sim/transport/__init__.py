"""Transports that put a simulated arm where a host reaches a real one: a pseudo-terminal
(`pty`) for a serial bus, and for a CAN bus python-can's in-process `virtual` interface or an
SLCAN adapter on a pseudo-terminal (`can`)."""
