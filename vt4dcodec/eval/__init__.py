"""Evaluation of the codec against ground truth: what docs/RESULTS.md reports.

It sits above the codec (it encodes and decodes through :mod:`vt4dcodec.codec`) and the networks, which
never import it.  Modules:

* :mod:`.protocol`: held-out synthetic scenes, the methods compared and how each predicts the target views;
* :mod:`.metrics`: PSNR, SSIM and region PSNR of one video, means with standard errors;
* :mod:`.report`: the per-method summary, the results file, the Markdown tables and the figures;
* :mod:`.baselines`: the nearest-source-frame and depth forward-warp baselines (numpy);
* :mod:`.real_footage`: the same comparison on real footage: any capture directory (or a caliscope
  recording), one or several encoded cameras, one or every camera rendered;
* :mod:`.command`: the command line, ``python -m vt4dcodec.eval`` (real footage:
  ``python -m vt4dcodec.eval.real_footage``).

Importing it imports torch; ``import vt4dcodec`` does not import it.
"""
