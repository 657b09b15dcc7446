"""ResNet backbones, graph layers, HOPE-Net and the ResNet regression baseline.

Modules: ``resnet`` (torchvision-named ResNet-10/18/34/50), ``graph`` (GraphConv,
node pooling, the adaptive Graph U-Net, the 2D refinement), ``hopenet``,
``baseline`` (ResNetRegressor), ``heatmap`` (HUPNet), ``model_config`` (what every model's frozen config
dataclass shares), ``build`` (``build_model`` from a saved config, strict checkpoint loading) and ``coords``
(pixels <-> normalised image coordinates).

May import: torch, numpy, itself and the shared core (``hupbench.core``: its check vocabulary and tolerances). Never
``datagen`` or the rest of ``hupbench``: a model is built from numbers (keypoint count, input size, the prior
layout), not from the generator or the CLI.
"""
