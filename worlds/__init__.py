"""The bundled world files, installed as ``apf_physics.worlds`` (see ``apf_physics.bundled``).

This file makes the folder a regular package so that an editable install maps it to this
checkout; the folder holds world files (YAML), no code.
"""
