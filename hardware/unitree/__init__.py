"""The Unitree SDK2 (DDS) adapter: legs over ``rt/lowcmd`` / ``rt/lowstate``."""
