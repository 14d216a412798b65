"""Hardware adapters: processes that speak the sim's keys to a real robot's SDK
(docs/hardware.md, docs/architecture.md "Hardware adapter contract")."""
