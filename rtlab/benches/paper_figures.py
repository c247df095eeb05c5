"""The paper's own figures (Shih et al. 2009, a GeForce 8800 GTS with CUDA 1.1, 1024x1024), once:
every bench that prints one beside ours takes it from here."""
from __future__ import annotations

PAPER_SIZE = 1024           # image side of every timed figure

# Table 2: #triangles, #nodes, #non-empty leaves, triangle refs per non-empty leaf, size
PAPER_TABLE2 = {"bunny": (69451, 379713, 120511, 2.72, "11MB"), "sponza": (66454, 292195, 124059, 2.63, "10MB"),
                "kitchen": (103343, 362585, 146253, 2.63, "14MB"), "dragon": (871414, 1687237, 607852, 2.59, "103MB")}

# Table 3: ms per launch of the 1000-triangle loop, and its "Reg. usage" row
PAPER_TABLE3_MS = {"bunny": {"moller": 515.3, "wald": 439.8, "plucker": 566.3},
                   "sponza": {"moller": 515.3, "wald": 431.5, "plucker": 578.7}}
PAPER_TABLE3_REGISTERS = {"moller": 12, "wald": 18, "plucker": 22}

# Table 4: fps, primary rays, simple shading ("-" where it gave none); registers and occupancy
PAPER_TABLE4_FPS = {
    "stack": {"bunny": 43.2, "sponza": 40.5, "kitchen": 39.6, "dragon": 30.4},
    "packet": {"bunny": 15.8, "sponza": 16.5},
    "restart": {"bunny": 30.9, "sponza": 28.6, "kitchen": 28.9, "dragon": 21.4},
    "shortstack": {"bunny": 31.7, "sponza": 29.5, "kitchen": 28.2, "dragon": 21.8},
    "ropes": {"bunny": 38.4, "sponza": 34.4, "kitchen": 33.4, "dragon": 26.4},
}
PAPER_TABLE4_REGISTERS = {"stack": 18, "packet": 20, "restart": 17, "shortstack": 28, "ropes": 24}
PAPER_TABLE4_OCCUPANCY = {"stack": 0.50, "packet": 0.50, "restart": 0.50, "shortstack": 0.33, "ropes": 0.33}

# Table 5: fps with shadows one- and two-pass, and with 1-3 bounces; registers and occupancy
PAPER_SHADOW_FPS = {"bunny": {"one-pass": 16.6, "two-pass": 18.4},
                    "sponza": {"one-pass": 21.0, "two-pass": 23.9},
                    "kitchen": {"one-pass": 18.1, "two-pass": 20.1}}
PAPER_BOUNCE_FPS = {"sponza": {1: 11.3, 2: 7.2, 3: 5.0}, "kitchen": {1: 9.1, 2: 5.9, 3: 3.9}}
PAPER_TABLE5_REGISTERS = {"one-pass": "22", "two-pass": "19/18"}
PAPER_TABLE5_OCCUPANCY = {"one-pass": "33%", "two-pass": "50%"}

# Fig. 4 (§4.1): the best block shapes, and those that "perform well"
PAPER_FIG4_BEST = ((2, 32), (4, 32))
PAPER_FIG4_GOOD = ((14, 32), (22, 20))
