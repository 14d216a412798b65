"""quadmanip.sim"""
