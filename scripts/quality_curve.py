#!/usr/bin/env python3
"""Markdown table of a `socdiff bench quality --score-every` run: every scored point from DIR/at-*min/quality.json
and DIR/quality.json, with the baselines of the last. Usage: python3 scripts/quality_curve.py DIR"""
import json,sys,glob,os
d=sys.argv[1]
files=sorted(glob.glob(d+'/at-*/quality.json'), key=lambda f: float(f.split('at-')[1].split('min')[0]))+[d+'/quality.json']
print('| minutes | step | ours 1 s | 2 s | 3 s | best of 8: 1 s | 2 s | 3 s | MRT ours 1 s | 2 s | 3 s | first-frame jump within observed |')
print('|---|---|---|---|---|---|---|---|---|---|---|---|')
for f in files:
    if not os.path.exists(f): continue
    q=json.load(open(f)); o=q['protocol']['ours']; mp=o['methods']['ours']['mpjpe_m']; mr=q['protocol']['mrt']['methods']['ours']
    mm=lambda v: '%.0f'%(v*1e3)
    print('| %s | %d | %s | %s | %s | %s | %s | %s | %s | %s | %s | %d of %d |'%(q['training']['minutes'], q['training']['step'], *[mm(mp[h]['global']['mean']) for h in ['1s','2s','3s']], *[mm(mp[h]['global']['best']) for h in ['1s','2s','3s']], *[mm(mr['mean'][h]) for h in ['1s','2s','3s']], o['first_frame_jump']['windows_within_observed'], o['windows']))
q=json.load(open(files[-1])); o=q['protocol']['ours']
for m in ['zero-velocity','constant-velocity','nearest']:
    mp=o['methods'][m]['mpjpe_m']; mr=q['protocol']['mrt']['methods'][m]
    print('| %s | | %s | | | | %s | |'%(m, ' | '.join('%.0f'%(mp[h]['global']['mean']*1e3) for h in ['1s','2s','3s']), ' | '.join('%.0f'%(mr['mean'][h]*1e3) for h in ['1s','2s','3s'])))
