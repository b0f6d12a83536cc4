"""The test suite; its folders mirror src/nerf_transporter/ (shared fixtures in conftest.py)."""
