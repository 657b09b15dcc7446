#version 330 core
// hupbench's colour pass: Lambert diffuse + normalised Blinn-Phong specular under point lamps, plus
// ambient and emissive light. Drop-in for pyrender's physically based mesh.frag (same uniform names,
// fed by pyrender's mesh.vert); the stored colour is linear ** (1 / 2.2), as pyrender writes it.
// In linear light a surface of albedo a under a lamp of colour c is ambient * a + k_d * a * c + k_s * c
// (+ emissive): datagen.dataset.verify_images reads the glove colours back on that plane.

struct PointLight {
    vec3 color;
    float intensity;
    vec3 position;
};

struct Material {
    vec3 emissive_factor;
    vec4 base_color_factor;
    float metallic_factor;
    float roughness_factor;
};

uniform Material material;
uniform PointLight point_lights[MAX_POINT_LIGHTS];
uniform int n_point_lights;
uniform vec3 cam_pos;
uniform vec3 ambient_light;

in vec3 frag_position;
#ifdef NORMAL_LOC
in vec3 frag_normal;
#endif

out vec4 frag_color;

const float PI = 3.141592653589793;
const float DIELECTRIC_F0 = 0.04;

void main()
{
    vec4 base = material.base_color_factor;
    float metallic = clamp(material.metallic_factor, 0.0, 1.0);
    float roughness = clamp(material.roughness_factor, 0.04, 1.0);
    // GGX's alpha = roughness^2; the Blinn-Phong exponent with the same highlight width
    float alpha = roughness * roughness;
    float shininess = max(2.0 / (alpha * alpha) - 2.0, 1.0);
    vec3 diffuse_albedo = base.rgb * (1.0 - DIELECTRIC_F0) * (1.0 - metallic);
    vec3 f0 = mix(vec3(DIELECTRIC_F0), base.rgb, metallic);

#ifdef NORMAL_LOC
    vec3 n = normalize(frag_normal);
#else
    vec3 n = normalize(cross(dFdx(frag_position), dFdy(frag_position)));
#endif
    vec3 v = normalize(cam_pos - frag_position);
    if (dot(n, v) < 0.0) {
        n = -n;  // the inside of an open mesh is lit like its outside
    }

    vec3 color = base.rgb * ambient_light;
    for (int i = 0; i < n_point_lights; i++) {
        vec3 to_light = point_lights[i].position - frag_position;
        float dist2 = dot(to_light, to_light);
        vec3 l = to_light * inversesqrt(dist2);
        float n_l = dot(n, l);
        if (n_l <= 0.0) {
            continue;
        }
        vec3 h = normalize(l + v);
        float specular = (shininess + 8.0) / (8.0 * PI) * pow(max(dot(n, h), 0.0), shininess);
        vec3 radiance = point_lights[i].color * (point_lights[i].intensity / dist2);
        color += radiance * n_l * (diffuse_albedo / PI + f0 * specular);
    }
    color += material.emissive_factor;
    frag_color = clamp(vec4(pow(color, vec3(1.0 / 2.2)), base.a), 0.0, 1.0);
}
