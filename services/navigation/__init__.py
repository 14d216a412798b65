"""Navigation: SLAM map, localisation, planning and control to body velocity commands
(paper Sections 5.1-5.3). Algorithms live in plain modules; ``node.py`` wires them to Zenoh."""
