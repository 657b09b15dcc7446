"""ResNet backbones, graph layers, HOPE-Net and the ResNet regression baseline.

Modules: ``resnet`` (torchvision-named ResNet-10/18/34/50), ``graph`` (GraphConv,
node pooling, the adaptive Graph U-Net, the 2D refinement), ``hopenet``,
``baseline`` (ResNetRegressor), ``build`` (registry, ``build_model``, strict
checkpoint loading), ``coords`` (pixels <-> normalised image coordinates) and
``tolerances``. Nothing here imports ``datagen`` or ``hupbench``.
"""
