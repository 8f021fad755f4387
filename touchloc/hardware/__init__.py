"""touchloc.hardware"""
