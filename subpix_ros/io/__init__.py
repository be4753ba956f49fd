"""Message conversion, bags and MAVLink, shared by all nodes and tools."""
