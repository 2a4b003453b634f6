"""Models on the microcontroller: what a step costs, ONNX, generated C, the emulated STM32."""
