"""The paper's IPMC: the virtual IPMC (an independent strip simulator that
stands in for a lab), synthetic strips with hidden effects, the Table 2
reproduction, the Cramér–Rao sensitivity study, and the paper's defaults
(the RC network as the physics of `make_model` and `diagnose`).
"""
