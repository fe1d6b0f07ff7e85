"""Broken PhotoModeler exports (generated from mini.txt, a 2-photo cut of camcal-pmexport.txt):
file -> (line, field) the InputError must name."""

CASES = {'header-short': (3, 'header'), 'header-tolerance': (2, 'max_iter'), 'header-size': (2, 'height'), 'camera-c': (4, 'P2'), 'camera-nan': (4, 'c'), 'photo-number': (6, 'photo'), 'photo-name': (6, 'name'), 'photo-outer': (7, 'omega'), 'photo-outer-number': (7, 'omega'), 'photo-wrong-number': (8, 'photo'), 'photo-inner': (10, 'yp'), 'object-columns': (20, 'y'), 'object-id': (20, 'id'), 'object-sigma': (20, 'sx'), 'object-twice': (21, 'id'), 'mark-number': (27, 'x'), 'mark-photo': (27, 'photo'), 'mark-columns': (27, 'sy'), 'mark-twice': (28, 'id'), 'mark-sigma': (27, 'sx'), 'no-marks': (None, 'marks')}
