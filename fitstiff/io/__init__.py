"""The measurement log and the files around it: the record (Log, Rig), the column contract and
units, reading CSV logs (with their screens), validation at the boundary, and writing results
without destroying anything."""
