"""touchloc.belief"""
