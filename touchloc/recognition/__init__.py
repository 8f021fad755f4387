"""touchloc.recognition"""
