"""Long runs that compare planners (paper 000 III-B, Fig. 9)."""
