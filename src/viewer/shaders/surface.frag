// csb viewer — two-sided Blinn-Phong lighting in eye space: a key light above and to the side of
// the camera and a dim fill from below, plus a sky/ground ambient term. Cloth has two sides:
// a fragment seen from behind flips its normal and takes the back colour, so that an open
// sheet is lit the same from either side and one can tell the sides apart.
#version 330 core

in vec3 v_position;
in vec3 v_normal;
in vec3 v_color;

uniform vec3 back_tint;       // multiplies the colour of back faces
uniform float specular;       // strength of the highlight, 0 for matte colliders

out vec4 frag_color;

void main() {
  vec3 n = normalize(v_normal);
  vec3 base = v_color;
  if (!gl_FrontFacing) {
    n = -n;
    base *= back_tint;
  }
  vec3 to_eye = normalize(-v_position);
  // A degenerate or edge-on normal must not turn black: face the viewer instead.
  if (any(isnan(n))) n = to_eye;

  const vec3 key_dir = normalize(vec3(0.4, 0.8, 0.6));   // eye space
  const vec3 fill_dir = normalize(vec3(-0.5, -0.3, 0.4));
  float key = max(dot(n, key_dir), 0.0);
  float fill = max(dot(n, fill_dir), 0.0);
  float hemi = 0.5 + 0.5 * n.y;  // sky above, ground below
  vec3 ambient = mix(vec3(0.18, 0.17, 0.16), vec3(0.32, 0.34, 0.38), hemi);
  vec3 h = normalize(key_dir + to_eye);
  float spec = specular * pow(max(dot(n, h), 0.0), 48.0) * step(0.0, key);

  vec3 linear = base * (ambient + 0.75 * key + 0.2 * fill) + vec3(spec);
  frag_color = vec4(pow(linear, vec3(1.0 / 2.2)), 1.0);  // to sRGB
}
