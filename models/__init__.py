"""ResNet backbones, graph layers, HOPE-Net and the ResNet regression baseline."""
