"""MuJoCo simulation of the WhiskEye-like robot (DESIGN §3-4)."""
