"""The protocol and rig schema: the YAML model (schema), its step plan and the catalogue of scenes."""
