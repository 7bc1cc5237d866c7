"""The reference keypoint CNN: network (torch), training recipe, ONNX export."""
