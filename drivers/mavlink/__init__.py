"""MAVLink vehicles: live links (UDP, TCP, serial) and the message-to-measurement decoder.

The modules are imported by name (``drivers.mavlink.link``, ``.signing``, ...): the package itself
loads none of them, so a light one (the signing key, the connection string) costs no decoder.
"""
