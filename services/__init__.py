"""quadmanip.services"""
