"""The planning commands (`plan`, `sweep`, registered under the entry-point group `jaxrobot.commands`) with
their tables and plots."""
