defmodule ThinkingCap.Control.Behaviour do
  @moduledoc """
  A fuzzy control behaviour: it maps the robot's situation (`t:inputs/0`)
  to fuzzy sets over the two control variables, and says by its **context**
  (a degree in [0, 1]) how much it applies now. `ThinkingCap.Control.Blend`
  weighs the behaviours' sets by their contexts, joins them and
  defuzzifies once.

  ## Control variables

  Every behaviour concludes on the same two output variables
  (`output_variables/1`), so that their sets can be joined:

    * `:v`, linear speed (m/s), universe `{-0.25 max_speed, max_speed}`,
      terms `:back`, `:stop`, `:slow`, `:medium`, `:fast`;
    * `:w`, turn rate (rad/s, counter-clockwise positive), universe
      `{-max_turn_rate, max_turn_rate}`, terms `:hard_right`, `:right`,
      `:straight`, `:left`, `:hard_left`.

  Terms are fractions of the limits (see `output_variables/1`), so a rule
  base reads the same on any robot.

  ## Writing one

      defmodule Creep do
        use ThinkingCap.Control.Behaviour

        @impl true
        def init(params), do: Map.new(params)

        @impl true
        def context(_inputs, _params), do: 1.0

        @impl true
        def outputs(inputs, _params),
          do: Behaviour.control([[if: true, then: [v: :slow, w: :straight]]], %{}, [], inputs)
      end

  `use` gives `evaluate/2` (context and outputs together); override it
  when both need the same costly quantities.
  """

  alias ThinkingCap.Control.Fuzzy
  alias ThinkingCap.Control.Fuzzy.{Set, Variable}
  alias ThinkingCap.Perception.LPS

  @typedoc "A point in the world frame, m."
  @type point :: {float(), float()}

  @typedoc "A door to cross (world frame): its centre, the direction through it, its width."
  @type door :: %{centre: point(), heading: float(), width: float()}

  @typedoc """
  What a behaviour sees:

    * `lps` - the Local Perceptual Space (robot frame);
    * `pose` - the estimated world pose `{x, y, θ}`;
    * `goal` - the world point to reach, or `nil`;
    * `path` - the current plan's world waypoints, or `nil`;
    * `door` - a door to cross (world frame), or `nil`;
    * `limits` - `max_speed` (m/s) and `max_turn_rate` (rad/s);
    * `radius` - the robot's radius (m);
    * `weights` (optional) - plan-given weights of behaviours by name,
      in [0, 1] (`ThinkingCap.Control.Blend`);
    * `last` (optional) - the command `{v, w}` the blend gave last cycle
      (what the robot is doing: a turn under way, say).
  """
  @type inputs :: %{
          required(:lps) => LPS.t(),
          required(:pose) => {float(), float(), float()},
          required(:goal) => point() | nil,
          required(:path) => [point()] | nil,
          required(:door) => door() | nil,
          required(:limits) => %{max_speed: float(), max_turn_rate: float()},
          required(:radius) => float(),
          optional(:weights) => %{atom() => float()},
          optional(:last) => {float(), float()}
        }

  @typedoc "Fuzzy sets over `:v` and `:w`; a missing one has no opinion."
  @type outputs :: %{optional(:v) => Set.t(), optional(:w) => Set.t()}

  @doc "The behaviour's parameters from a keyword list (defaults filled in)."
  @callback init(params :: keyword()) :: term()

  @doc "How much the behaviour applies now, in [0, 1]."
  @callback context(inputs(), params :: term()) :: float()

  @doc "The behaviour's fuzzy sets over `:v` and `:w`."
  @callback outputs(inputs(), params :: term()) :: outputs()

  @doc "Context and outputs at once."
  @callback evaluate(inputs(), params :: term()) :: {float(), outputs()}

  defmacro __using__(_opts) do
    quote do
      @behaviour ThinkingCap.Control.Behaviour
      alias ThinkingCap.Control.Behaviour

      @impl true
      def evaluate(inputs, params), do: {context(inputs, params), outputs(inputs, params)}

      defoverridable evaluate: 2
    end
  end

  @doc """
  The output variables for the given limits. With `V = max_speed` and
  `W = max_turn_rate`:

  | `:v` term | shape | `:w` term | shape |
  |---|---|---|---|
  | `:back` | left shoulder −0.25V → 0 | `:hard_right` | trapezoid −W, −W, −0.9W, −0.5W |
  | `:stop` | triangle −0.125V, 0, 0.125V | `:right` | triangle −0.8W, −0.4W, 0 |
  | `:slow` | triangle 0, 0.25V, 0.5V | `:straight` | triangle −0.2W, 0, 0.2W |
  | `:medium` | triangle 0.25V, 0.5V, 0.75V | `:left` | triangle 0, 0.4W, 0.8W |
  | `:fast` | trapezoid 0.5V, 0.9V, V, V | `:hard_left` | trapezoid 0.5W, 0.9W, W, W |

  All corners fall on the 101 samples of an output set.
  """
  @spec output_variables(%{max_speed: number(), max_turn_rate: number()}) :: [Variable.t()]
  def output_variables(%{max_speed: vmax, max_turn_rate: wmax}) do
    [
      Fuzzy.variable(:v, {-0.25 * vmax, vmax},
        back: {:left_shoulder, -0.25 * vmax, 0.0},
        stop: {:triangle, -0.125 * vmax, 0.0, 0.125 * vmax},
        slow: {:triangle, 0.0, 0.25 * vmax, 0.5 * vmax},
        medium: {:triangle, 0.25 * vmax, 0.5 * vmax, 0.75 * vmax},
        fast: {:trapezoid, 0.5 * vmax, 0.9 * vmax, vmax, vmax}
      ),
      Fuzzy.variable(:w, {-wmax, wmax},
        hard_right: {:trapezoid, -wmax, -wmax, -0.9 * wmax, -0.5 * wmax},
        right: {:triangle, -0.8 * wmax, -0.4 * wmax, 0.0},
        straight: {:triangle, -0.2 * wmax, 0.0, 0.2 * wmax},
        left: {:triangle, 0.0, 0.4 * wmax, 0.8 * wmax},
        hard_left: {:trapezoid, 0.5 * wmax, 0.9 * wmax, wmax, wmax}
      )
    ]
  end

  @doc """
  Evaluates a behaviour's rule base: `crisp` are the quantities it
  computed from the inputs, `variables` their linguistic variables; the
  output variables come from `inputs.limits`.
  """
  @spec control(Fuzzy.rule_base(), %{atom() => number()}, [Variable.t()], inputs()) :: outputs()
  def control(rules, crisp, variables, inputs),
    do: Fuzzy.evaluate(rules, crisp, variables ++ output_variables(inputs.limits))

  @doc """
  Context and outputs of a behaviour given as `{module, params}`, the
  context clamped to [0, 1].
  """
  @spec evaluate({module(), term()}, inputs()) :: {float(), outputs()}
  def evaluate({module, params}, inputs) do
    {context, outputs} = module.evaluate(inputs, params)
    {context |> max(0.0) |> min(1.0), outputs}
  end

  @doc "Mirrors a rule base left to right (turn terms swapped; see `mirror_term/1`)."
  @spec mirror(Fuzzy.rule_base()) :: Fuzzy.rule_base()
  def mirror(rules) do
    Enum.map(rules, fn rule ->
      Keyword.update!(rule, :then, fn conclusions ->
        Enum.map(conclusions, fn
          {:w, term} -> {:w, mirror_term(term)}
          other -> other
        end)
      end)
    end)
  end

  @doc "The mirror image of a `:w` term (`:left` ↔ `:right`, `:hard_left` ↔ `:hard_right`)."
  @spec mirror_term(atom()) :: atom()
  def mirror_term(:left), do: :right
  def mirror_term(:right), do: :left
  def mirror_term(:hard_left), do: :hard_right
  def mirror_term(:hard_right), do: :hard_left
  def mirror_term(term), do: term
end
