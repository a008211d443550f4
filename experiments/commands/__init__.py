"""The hec commands: one module per verb, and the table of verbs (hec.commands.table)."""
