"""The paper's published check-point results (paper 001, Tables 2–4), which the control study, the
method study and their figures set beside the simulated ones.  Its own module so that the figures
need not import the stages that draw them (no import cycle)."""

PAPER_TABLE2 = {  # case: (dof, sigma0 µm, Sx, Sy, Sxy, Sz) cm
    1: (34, 51.90, 0.3253, 0.0984, 0.2403, 4.6310), 2: (46, 47.78, 0.0768, 0.0334, 0.0592, 0.3110),
    3: (46, 45.35, 0.0813, 0.0348, 0.0625, 0.3485), 4: (87, 38.63, 0.0691, 0.0299, 0.0533, 0.2475),
    5: (82, 41.15, 0.0747, 0.0305, 0.0570, 0.2301), 6: (92, 39.91, 0.0824, 0.0271, 0.0613, 0.2905),
}
PAPER_TABLE3 = {  # case: (Sx, Sy, Sxy, Sz) cm, APs kept
    1: (0.3022, 0.0943, 0.2238, 2.9455, "b1 b2 b3 b4 b5 b6 b7 b9 b11"),
    2: (0.0715, 0.0301, 0.0549, 0.2902, "b1 b2 b7 b8 b12"), 3: (0.0760, 0.0306, 0.0579, 0.3125, "b1 b2 b3 b7 b11"),
    4: (0.0641, 0.0270, 0.0492, 0.2206, "b3 b4 b6 b7 b8 b12"), 5: (0.0701, 0.0279, 0.0533, 0.2155, "b3 b5 b6 b8 b12"),
    6: (0.0779, 0.0250, 0.0579, 0.2741, "b3 b9 b10 b11"),
}
PAPER_TABLE4 = {"single model": (0.0704, 0.0466, 0.0597, 0.2398), "block": (0.0701, 0.0279, 0.0533, 0.2155)}
