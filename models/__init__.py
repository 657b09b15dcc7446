"""ResNet backbones, graph layers, HOPE-Net and the ResNet regression baseline.

Modules: ``resnet`` (torchvision-named ResNet-10/18/34/50), ``graph`` (GraphConv,
node pooling, the adaptive Graph U-Net, the 2D refinement), ``hopenet``,
``baseline`` (ResNetRegressor), ``heatmap`` (HUPNet), ``config`` (what every model's frozen config
dataclass shares), ``build`` (``build_model`` from a saved config, strict checkpoint loading), ``coords``
(pixels <-> normalised image coordinates) and ``model_tolerances``.

May import: torch, numpy, itself and the shared core (``hupbench.core``: its check vocabulary). Never
``datagen`` or the rest of ``hupbench``: a model is built from numbers (keypoint count, input size, the prior
layout), not from the generator or the CLI.
"""
