#version 450
// mimicgen_pipe's cheap camera shader (see gbuffer.frag): SAPIEN's minimal vertex stage less
// its per-vertex matrix inverse and tangent frame. Every body's transform is a rotation and a
// translation (scales are baked into the meshes or uniform), so the model-view matrix turns
// normals as it turns directions.

layout(set = 0, binding = 0) uniform CameraBuffer {
  mat4 viewMatrix;
  mat4 projectionMatrix;
  mat4 viewMatrixInverse;
  mat4 projectionMatrixInverse;
  float width;
  float height;
} cameraBuffer;

layout(set = 1, binding = 0) uniform ObjectTransformBuffer {
  mat4 modelMatrix;
} objectTransformBuffer;

// unused, but SAPIEN reads the object set's layout from here (without it: map::at)
layout(set = 1, binding = 1) uniform ObjectDataBuffer {
  uvec4 segmentation;
  float transparency;
  int shadeFlat;
} objectDataBuffer;

layout(location = 0) in vec3 position;
layout(location = 1) in vec3 normal;
layout(location = 2) in vec2 uv;
// unused, but every pack's vertex layout must be the same as the others' in one process
layout(location = 3) in vec3 tangent;
layout(location = 4) in vec3 bitangent;

layout(location = 0) out vec2 outUV;
layout(location = 1) out vec3 outNormal;

void main() {
  mat4 modelView = cameraBuffer.viewMatrix * objectTransformBuffer.modelMatrix;
  outUV = uv;
  outNormal = mat3(modelView) * normal;  // normalised per fragment
  gl_Position = cameraBuffer.projectionMatrix * (modelView * vec4(position, 1));
}
