"""The synthetic multi-camera dynamic scene generator."""
