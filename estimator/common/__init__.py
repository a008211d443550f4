"""The bottom of the library: file helpers and small shared types; it imports nothing else of hec."""
