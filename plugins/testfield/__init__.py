"""The simulated test field of paper 001 (Park & Yeu): one plugin, four stages.

* ``testfield`` (:mod:`.source`) — the field as a block, with its truth;
* ``testfield-render`` (:mod:`.render`, :mod:`.photos`, :mod:`.drawing`, :mod:`.truth`) — its photos
  rendered through the distorted camera, for target detection;
* ``testfield-control-study`` (:mod:`.control_study`) — Tables 2–4: six control configurations with
  and without additional parameters;
* ``testfield-method-study`` (:mod:`.method_study`, :mod:`.method_study_stage`) — Tables 4 and 5:
  bundle, independent models, single model against block.

The field itself (geometry, control cases, systematic errors) is the seeded simulator
:mod:`baarda.pipeline.synthetic.testfield`.  See ``docs/testfield.md`` and ``docs/method-study.md``.
"""
