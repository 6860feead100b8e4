defmodule ThinkingCap.Control do
  @moduledoc """
  The control layer of the cognitive architecture: fuzzy behaviours
  blended by context (ThinkingCap-II, after Saffiotti's context-dependent
  blending).

    * `ThinkingCap.Control.Fuzzy` - the fuzzy engine: membership functions,
      linguistic variables, rule bases as data, Mamdani inference (min/max,
      clipping), sampled output sets, centroid defuzzification;
    * `ThinkingCap.Control.Behaviour` - what a behaviour is: fuzzy sets over
      speed `:v` and turn rate `:w` from the robot's situation (LPS, pose,
      goal, path, door), and a context saying how much it applies;
    * the behaviours: `ThinkingCap.Control.AvoidObstacles`,
      `ThinkingCap.Control.FollowWall`, `ThinkingCap.Control.CrossDoor`,
      `ThinkingCap.Control.GoToPoint`, `ThinkingCap.Control.FollowPath`,
      and the crisp quantities they fuzzify, `ThinkingCap.Control.Geometry`;
    * `ThinkingCap.Control.Blend` - context-dependent blending, itself a
      behaviour (composites);
    * `ThinkingCap.Control.Blender` - the control cycle as a
      `ThinkingCap.Module`: LPS, pose and plan in; drive command and
      activations out.
  """

  @behaviours %{
    avoid: ThinkingCap.Control.AvoidObstacles,
    follow_wall: ThinkingCap.Control.FollowWall,
    cross_door: ThinkingCap.Control.CrossDoor,
    go_to: ThinkingCap.Control.GoToPoint,
    follow_path: ThinkingCap.Control.FollowPath
  }

  @doc """
  The behaviours known by name (as in an ADF's `behaviours:` list) and
  their modules.
  """
  @spec behaviours() :: %{atom() => module()}
  def behaviours, do: @behaviours
end
