"""Log-file readers: the formats real vehicles leave behind, to measurements."""
