"""hybridsplat: the application layer — CLI, pipeline stages, manifest and configuration."""

__version__ = "0.1.0"
