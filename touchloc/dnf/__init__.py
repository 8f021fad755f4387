"""touchloc.dnf"""
