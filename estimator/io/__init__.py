"""Files: the dataset format, JSON reading, atomic writes, the shipped models/ folder."""
