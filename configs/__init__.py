"""quadmanip.configs"""
