"""Attitude determination (Yoon 2017, Ch. 4-5): the MEKF baseline, the APKF, Monte Carlo campaigns on Dask."""
