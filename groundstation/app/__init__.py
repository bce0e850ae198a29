"""The application: the ``groundstation`` command line and the wiring of its sessions."""
