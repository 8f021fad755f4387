"""touchloc.planners"""
