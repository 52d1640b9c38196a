#version 450
// mimicgen_pipe's cheap camera shader: one pass straight to Color (no composite pass, no
// position or segmentation targets), the base colour lit by the ambient light and the
// scene's directional lights (Lambert, their count set by SAPIEN by name); no specular,
// image-based light (black where no environment map is set, as in ManiSkill's table scenes),
// shadows, point or spot lights. On lavapipe SAPIEN's minimal pack spends most of a small
// picture's per-pixel time on its environment-map lookups and GGX terms.

layout (constant_id = 0) const int NUM_DIRECTIONAL_LIGHTS = 0;

layout(set = 0, binding = 0) uniform CameraBuffer {
  mat4 viewMatrix;
  mat4 projectionMatrix;
  mat4 viewMatrixInverse;
  mat4 projectionMatrixInverse;
  float width;
  float height;
} cameraBuffer;

layout(set = 2, binding = 0) uniform MaterialBuffer {
  vec4 emission;
  vec4 baseColor;
  float fresnel;
  float roughness;
  float metallic;
  float transmission;
  float ior;
  float transmissionRoughness;
  int textureMask;
  int padding1;
  vec4 textureTransforms[6];
} materialBuffer;

layout(set = 2, binding = 1) uniform sampler2D colorTexture;

struct PointLight {
  vec4 position;
  vec4 emission;
};

struct DirectionalLight {
  vec4 direction;
  vec4 emission;
};

struct SpotLight {
  vec4 position;
  vec4 direction;
  vec4 emission;
};

layout(set = 3, binding = 0) uniform SceneBuffer {
  vec4 ambientLight;
  PointLight pointLights[10];
  DirectionalLight directionalLights[3];
  SpotLight spotLights[10];
  SpotLight texturedLights[1];
} sceneBuffer;

layout(location = 0) in vec2 inUV;
layout(location = 1) in vec3 inNormal;

layout(location = 0) out vec4 outColor;

void main() {
  vec4 albedo;
  if ((materialBuffer.textureMask & 1) != 0) {
    albedo = texture(colorTexture, inUV * materialBuffer.textureTransforms[0].zw +
                                   materialBuffer.textureTransforms[0].xy);
  } else {
    albedo = materialBuffer.baseColor;
  }
  vec3 normal = normalize(inNormal);
  vec3 light = sceneBuffer.ambientLight.rgb;
  for (int i = 0; i < NUM_DIRECTIONAL_LIGHTS; ++i) {
    vec3 l = -(mat3(cameraBuffer.viewMatrix) * sceneBuffer.directionalLights[i].direction.xyz);
    light += sceneBuffer.directionalLights[i].emission.rgb * max(dot(normal, l), 0) / 3.14159265;
  }
  vec3 color = materialBuffer.emission.rgb + albedo.rgb * light;
  outColor = vec4(pow(clamp(color, vec3(0), vec3(1)), vec3(1 / 2.2)), 1);
}
